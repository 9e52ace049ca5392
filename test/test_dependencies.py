"""Every third-party module the package imports is a declared dependency.

Imports are read from the source (ast, function-level imports included) and mapped to the
installed distributions that provide them (importlib.metadata.packages_distributions). Plain
PyPI modules must be named in setup.py's install_requires, and have a rosdep key in
package.xml; ROS modules (rclpy, message packages) come from the 'ros' extra without a ROS
install and are exec_depends in package.xml. A dependency reached only through another one
(for example a module that rosbags happens to bring) does not count: it can go away with an update.
"""

from __future__ import annotations

import ast
from collections.abc import Iterator
from importlib import metadata
import re
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

from packaging.requirements import Requirement

REPO = Path(__file__).resolve().parent.parent
PACKAGE = REPO / 'gyro_ekf'
# The standard library, with what later Pythons add that the package imports when present
# (compression.zstd: 3.14, tried before backports.zstd).
STDLIB = sys.stdlib_module_names | {'compression'}
# Extras whose modules the package may import, inside the function that needs them only
# (the package then imports without them): the benchmark's reference filter.
OPTIONAL_EXTRAS = ('bench',)
# ROS message packages a real Jazzy install has and PyPI does not: imported inside a function
# that copes with their absence (ekf_node's TF broadcast), and exec_depends in package.xml.
ROS_INSTALL_ONLY = {'tf2_msgs'}
# rosdep key of each imported PyPI distribution, None where rosdep has none and pip brings
# it (backports.zstd comes with rosbags, which is itself a pip key).
ROSDEP_KEYS = {
    'numpy': 'python3-numpy', 'scipy': 'python3-scipy', 'pyyaml': 'python3-yaml',
    'rosbags': 'python3-rosbags-pip', 'matplotlib': 'python3-matplotlib',
    'tqdm': 'python3-tqdm', 'lz4': 'python3-lz4', 'backports-zstd': None,
}


def _normalized(name: str) -> str:
    """PEP 503 form of a distribution name."""
    return re.sub(r'[-_.]+', '-', name).lower()


def setup_keywords() -> dict[str, object]:
    """install_requires and extras_require of setup.py, read from its syntax tree."""
    tree = ast.parse((REPO / 'setup.py').read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.Call) and getattr(node.func, 'id', None) == 'setup':
            return {k.arg: ast.literal_eval(k.value) for k in node.keywords
                    if k.arg in ('install_requires', 'extras_require')}
    raise AssertionError('setup.py has no setup(...) call')


def _names(requirements: list[str]) -> set[str]:
    """Distribution names of the requirements that apply to this Python."""
    parsed = [Requirement(text) for text in requirements]
    return {_normalized(r.name) for r in parsed if r.marker is None or r.marker.evaluate()}


def third_party_imports() -> dict[str, list[tuple[str, bool]]]:
    """Top-level module -> [(file:line, imported inside a function)] for non-stdlib imports."""
    found: dict[str, list[tuple[str, bool]]] = {}
    for source in sorted(PACKAGE.rglob('*.py')):
        tree = ast.parse(source.read_text(), str(source))
        for node, lazy in _imports(tree, False):
            modules = ([alias.name for alias in node.names] if isinstance(node, ast.Import)
                       else [node.module] if node.level == 0 and node.module else [])
            for module in modules:
                top = module.split('.')[0]
                if top in STDLIB or top == 'gyro_ekf':
                    continue
                where = f'{source.relative_to(REPO)}:{node.lineno}'
                found.setdefault(top, []).append((where, lazy))
    return found


def _imports(node: ast.AST, lazy: bool) -> Iterator[tuple[ast.Import | ast.ImportFrom, bool]]:
    for child in ast.iter_child_nodes(node):
        if isinstance(child, (ast.Import, ast.ImportFrom)):
            yield child, lazy
        inner = lazy or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef))
        yield from _imports(child, inner)


def _closure(requirements: set[str]) -> set[str]:
    """The distributions and everything they require, as installed here (normalized)."""
    seen: set[str] = set()
    todo = list(requirements)
    while todo:
        name = todo.pop()
        if name in seen:
            continue
        seen.add(name)
        try:
            requires = metadata.requires(name) or []
        except metadata.PackageNotFoundError:
            continue
        todo += [_normalized(Requirement(text).name) for text in requires
                 if 'extra ==' not in text]
    return seen


def _exec_depends() -> set[str]:
    root = ET.parse(REPO / 'package.xml').getroot()
    return {element.text for element in root.findall('exec_depend')}


def test_third_party_imports_are_found_in_the_source():
    imports = third_party_imports()
    # The scan sees module-level and function-level imports alike.
    assert 'numpy' in imports and not all(lazy for _, lazy in imports['numpy'])
    assert 'rclpy' in imports and any(lazy for _, lazy in imports['rclpy'])


def test_every_third_party_import_is_a_declared_dependency():
    keywords = setup_keywords()
    required = _names(keywords['install_requires'])
    extras = {name: _names(reqs) for name, reqs in keywords['extras_require'].items()}
    ros = _closure(extras['ros'])
    providers = metadata.packages_distributions()
    problems = []
    for module, sites in sorted(third_party_imports().items()):
        where = ', '.join(site for site, _ in sites[:3])
        dists = {_normalized(d) for d in providers.get(module, [])}
        if module in ROS_INSTALL_ONLY and not dists:
            if not all(lazy for _, lazy in sites):
                problems.append(f'{module} ({where}): not on PyPI, yet imported at module '
                                'level')
            continue
        if not dists:
            problems.append(f'{module} ({where}): no installed distribution provides it')
        elif any(d.startswith('ros-') for d in dists):
            if not dists & ros:
                problems.append(f'{module} ({where}): not brought by the ros extra')
        elif dists & required:
            continue
        elif any(dists & extras[e] for e in OPTIONAL_EXTRAS):
            if not all(lazy for _, lazy in sites):
                problems.append(f'{module} ({where}): only in an optional extra, yet imported '
                                'at module level')
        else:
            problems.append(f'{module} ({where}): provided by {sorted(dists)}, which '
                            'install_requires does not name')
    assert not problems, '\n'.join(problems)


def test_package_xml_declares_every_imported_dependency():
    root = ET.parse(REPO / 'package.xml').getroot()
    assert root.get('format') == '3'
    assert root.find('export/build_type').text == 'ament_python'
    exec_depends = _exec_depends()
    providers = metadata.packages_distributions()
    ros_modules = {module for module in third_party_imports()
                   if any(d.startswith('ros-') for d in providers.get(module, []))
                   or module in ROS_INSTALL_ONLY}
    # A ROS package's Python module has the package's name.
    assert ros_modules >= {'rclpy', 'sensor_msgs', 'nav_msgs'}
    missing = sorted(ros_modules - exec_depends)
    assert not missing, f'package.xml lacks <exec_depend> for {missing}'
    imported = {_normalized(d) for module in third_party_imports() if module not in ros_modules
                for d in providers.get(module, [])}
    runtime = _names(setup_keywords()['install_requires']) & imported
    unknown = sorted(runtime - ROSDEP_KEYS.keys())
    assert not unknown, f'no rosdep key known for {unknown}: add it to ROSDEP_KEYS'
    keys = {ROSDEP_KEYS[name] for name in runtime} - {None}
    missing = sorted(keys - exec_depends)
    assert not missing, f'package.xml lacks <exec_depend> for {missing}'
    assert {e.text for e in root.findall('test_depend')} >= {'python3-pytest'}

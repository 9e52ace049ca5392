"""docs/bad-input.md names real tests: every `file.py::test_name` it cites exists."""
import re
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def _test_files() -> dict[str, list[Path]]:
    files: dict[str, list[Path]] = {}
    for path in (REPO / 'test').rglob('test_*.py'):
        files.setdefault(path.name, []).append(path)
    return files


def test_every_test_the_bad_input_page_cites_exists():
    text = (REPO / 'docs' / 'bad-input.md').read_text()
    files = _test_files()
    missing = []
    cited = 0
    for row in text.splitlines():
        if not row.startswith('|'):
            continue
        last_file = None
        for match in re.finditer(r'(test/[\w/]+\.py|test_\w+\.py)?::(\w+)|(test/[\w/]+\.py)',
                                 row):
            name, function, bare = match.groups()
            path_text = name or bare
            if path_text:
                candidates = ([REPO / path_text] if '/' in path_text
                              else files.get(path_text, []))
                candidates = [p for p in candidates if p.exists()]
                if not candidates:
                    missing.append(path_text)
                    continue
                last_file = candidates
            if function and last_file:
                cited += 1
                if not any(re.search(rf'^def {function}\b', p.read_text(), re.M)
                           for p in last_file):
                    missing.append(f'{last_file[0].relative_to(REPO)}::{function}')
    assert cited > 20, 'the page should cite tests by name'
    assert not missing, missing

"""The project's fuzzer (`make fuzz`, `python -m fuzz --help`): see fuzz/harness.py."""

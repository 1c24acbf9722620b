"""The second robustness corpus: hostile inputs made by code, run through the real commands
(``python -m support.robustness.corpus`` with ``tests`` on the path; docs/robustness.md)."""

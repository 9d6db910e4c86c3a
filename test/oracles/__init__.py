"""Slow exact references that keep the fast paths honest (test code, not in the wheel).

Importable as ``oracles.<module>`` from the tests: pytest puts ``test/`` (the directory of the
top-level ``conftest.py``, which has no ``__init__.py``) on ``sys.path``; scripts such as
``benchmarks/bench_pipeline.py`` add it themselves.
"""

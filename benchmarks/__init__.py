"""Benchmarks: each ``bench_*.py`` module has ``main(quick: bool = False) -> list[str]`` and
prints figures with ratios against a baseline measured in the same run. Not tests: no
assertions on speed. Run all with ``python -m benchmarks`` (``--quick`` for a short run)."""

"""Test and benchmark harness: private meshes of real node processes, and a real browser driver.

Not part of the product's processes: `tests/` and `simecs.benchmarks` use it; no node imports it.
"""

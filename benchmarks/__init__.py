"""Measurements behind the figures in the docs, one script per question; run each from the repository
root as ``python -m benchmarks.NAME [ARGS]`` (``--help`` lists its arguments).

Code that tests use lives in the library (``phyir``) or in ``tests/support/``, never here: the tests
import no benchmark.  Timings of the library's own operations are ``phyir bench`` (``phyir/bench``);
the viewer's GL timings are in ``viewer/``.
"""

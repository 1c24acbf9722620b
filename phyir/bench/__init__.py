"""``phyir bench`` and the robustness tools: the harness (measure, report), every benchmark target, and the
file-reader fuzzer (``python -m phyir.bench.fuzz``)."""

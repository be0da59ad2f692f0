"""Harness: the benchmark protocol (:mod:`.protocol`), verification (:mod:`.verify`) and studies
(:mod:`.studies`).  It never imports ``reports`` or the API (``iblbench``); see ARCHITECTURE.md."""

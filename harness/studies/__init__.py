"""Studies: ``reproduce`` (papers' figures and claims with verdicts) and ``perf`` (throughput
against the roofline and a NumPy floor).  They return tables and objects; ``reports`` turns them
into HTML, called from the API, so ``harness`` never imports ``reports``."""

"""The runtime every estimator stands on: the OpenCL device and its program cache, the
G-buffer on the device, the frame cache (CDFs, light pool, mip pyramids), the exact reference and
the device probes (the FMA and copy kernels, and the timing floor's launches).

It imports only :mod:`iblbench.scenes` and itself, never ``harness``, ``reports`` or the API."""

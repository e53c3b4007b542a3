// Shared constants. No #version: the preprocessor adds it (README.md).
const float PI = 3.14159265358979;
const float INV_PI = 0.31830988618379;

// Clamped-cosine convolution folded into the SH basis constants (RH01 eq 8; workers/kernels/sh.py):
const float SH_IRR_C0 = 0.886227;  // π · c0 = π · 0.282095
const float SH_IRR_C1 = 1.023328;  // (2π/3) · c1 = (2π/3) · 0.488603

// Shared constants. No #version: the preprocessor adds it (README.md).
const float PI = 3.14159265358979;
const float INV_PI = 0.31830988618379;

// Clamped-cosine convolution folded into the SH basis constants (RH01 eq 8; workers/kernels/sh.py):
const float SH_IRR_C0 = 0.886227;  // π · c0 = π · 0.282095
const float SH_IRR_C1 = 1.023328;  // (2π/3) · c1 = (2π/3) · 0.488603
const float SH_IRR_C2 = 0.858086;  // (π/4) · c2 = (π/4) · 1.092548   (xy, yz, xz)
const float SH_IRR_C3 = 0.247708;  // (π/4) · c3 = (π/4) · 0.315392   (3z² − 1)
const float SH_IRR_C4 = 0.429043;  // (π/4) · c4 = (π/4) · 0.546274   (x² − y²)

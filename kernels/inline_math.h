/* Scalar floor, clamp, min, max and isfinite without builtin calls, where the host asks for
 * them (-DCLSS_INLINE_MATH=1: the frame kernels' fast paths on PoCL). Pip's PoCL 3.0 links
 * its kernel library, built for haswell, into kernels built for the host CPU, and LLVM does
 * not inline across that mismatch: each floor, clamp, min or isfinite is a call, and a call
 * in the work-item loop stops PoCL's vectoriser, so a per-pixel kernel runs one pixel at a
 * time through a dozen calls. The forms below give the builtin's result for every argument
 * these kernels pass (finite, |x| < 2^31; clss_isfinite for any float), so the fast path
 * is bit-exact; =0 (the reference, and every other device) calls the builtins. Include
 * after common.h; with FP_CONTRACT OFF or on, nothing here contracts. */
#ifndef CLSS_INLINE_MATH_H
#define CLSS_INLINE_MATH_H

#ifndef CLSS_INLINE_MATH
#define CLSS_INLINE_MATH 0
#endif

#if CLSS_INLINE_MATH
/* (int)floor(x): truncation, one down where that rounded up (x negative, not whole) */
static inline int clss_floori(float x) { const int i = (int)x; return (float)i > x ? i - 1 : i; }
static inline int clss_clampi(int v, int lo, int hi) { return v < lo ? lo : (v > hi ? hi : v); }
/* clamp(v, lo, hi) = fmin(fmax(v, lo), hi): a NaN gives lo, as fmax ignores it */
static inline float clss_clampf(float v, float lo, float hi) { return v > lo ? (v < hi ? v : hi) : lo; }
/* fmax(a, b) for a, b not NaN */
static inline float clss_fmaxf(float a, float b) { return a > b ? a : b; }
/* fabs: the sign bit cleared */
static inline float clss_fabsf(float v) { return as_float(as_uint(v) & 0x7fffffffu); }
static inline int clss_mini(int a, int b) { return a < b ? a : b; }
static inline int clss_maxi(int a, int b) { return a > b ? a : b; }
/* isfinite: v - v is 0 for finite v, NaN for an infinity or a NaN */
static inline int clss_isfinite(float v) { return (v - v) == 0.0f; }
#else
static inline int clss_floori(float x) { return (int)floor(x); }
static inline int clss_clampi(int v, int lo, int hi) { return clamp(v, lo, hi); }
static inline float clss_clampf(float v, float lo, float hi) { return clamp(v, lo, hi); }
static inline float clss_fmaxf(float a, float b) { return fmax(a, b); }
static inline float clss_fabsf(float v) { return fabs(v); }
static inline int clss_mini(int a, int b) { return min(a, b); }
static inline int clss_maxi(int a, int b) { return max(a, b); }
static inline int clss_isfinite(float v) { return isfinite(v); }
#endif

#endif

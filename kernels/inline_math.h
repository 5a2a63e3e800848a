/* Floor, clamp, min, max, fabs and isfinite without builtin calls, where the host asks for
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

/* fmin, fmax, floor and fabs overloaded on float, float4 and float8 (the CLSS frame
 * kernels' vectors, clss/methods/clss/frame.cl): fmin/fmax as a comparison and a select
 * (the lane of b where b < a, else a's: the builtin's result for every pair but a NaN, and
 * a zero of the other sign); floor by the conversion to int and back (|x| < 2^31; -0 gives
 * +0); fabs by the sign bit. Not llvm's minnum, maxnum and floor intrinsics, which
 * oclgrind cannot run. */
#define CLSS_OVL static inline __attribute__((overloadable))
CLSS_OVL float fmin_q(float a, float b) { return b < a ? b : a; }
CLSS_OVL float fmax_q(float a, float b) { return b > a ? b : a; }
CLSS_OVL float floor_q(float x) { const float t = (float)(int)x; return t > x ? t - 1.0f : t; }
CLSS_OVL float fabs_q(float x) { return as_float(as_uint(x) & 0x7fffffffu); }
#define CLSS_INLINE_MATH_VEC(F, I)                                                          \
CLSS_OVL F fmin_q(F a, F b) { return b < a ? b : a; }                                       \
CLSS_OVL F fmax_q(F a, F b) { return b > a ? b : a; }                                       \
CLSS_OVL F fmin_q(F a, float b) { return fmin_q(a, (F)(b)); }                               \
CLSS_OVL F fmax_q(F a, float b) { return fmax_q(a, (F)(b)); }                               \
CLSS_OVL F floor_q(F x)                                                                     \
{                                                                                           \
    const F t = __builtin_convertvector(__builtin_convertvector(x, I), F);                  \
    return t > x ? t - 1.0f : t;                                                            \
}                                                                                           \
CLSS_OVL F fabs_q(F x) { return __builtin_astype(__builtin_astype(x, I) & 0x7fffffff, F); }
CLSS_INLINE_MATH_VEC(float4, int4)
CLSS_INLINE_MATH_VEC(float8, int8)
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

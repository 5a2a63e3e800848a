/* common.h: storage and compute types shared by every clss kernel.
 *
 * One source per operator; precision is chosen at build time with -D options,
 * never by copying a kernel:
 *
 *   (none)            fp32: float storage, float arithmetic
 *   -DCLSS_FP16       half storage (vload_half/vstore_half, core OpenCL 1.2),
 *                     float arithmetic. Works on every device, PoCL included.
 *   -DCLSS_FP16_NATIVE half storage and half arithmetic; needs cl_khr_fp16.
 *
 * Kernels use:
 *   T            the storage element type of tensor buffers (__global T *)
 *   TB           an unsigned integer of T's size: pure data movement copies
 *                bits through it (bit-exact, NaN payloads kept, and no half
 *                dereference, which OpenCL 1.2 allows only with cl_khr_fp16)
 *   A, A4, A8    the arithmetic (accumulator) type and its vectors
 *   LD(p, i)     load element i of p as A
 *   ST(p, i, v)  store A v to element i of p (round-to-nearest-even in fp16)
 *   LD4/LD8(p, i), ST4/ST8(p, i, v)  vector forms; i is an element offset, no
 *                alignment needed beyond the element type.
 *
 * The clss host prepends this file to each source, so the kernels also build
 * with a plain `#include "common.h"` and -I kernels/ in a vendor's own tools.
 */
#ifndef CLSS_COMMON_H
#define CLSS_COMMON_H

#if defined(CLSS_FP16_NATIVE)
#pragma OPENCL EXTENSION cl_khr_fp16 : enable
typedef half T;
typedef ushort TB;
typedef half A;
typedef half4 A4;
typedef half8 A8;
#define LD(p, i) ((p)[(i)])
#define ST(p, i, v) ((p)[(i)] = (half)(v))
#define LD4(p, i) vload4(0, (p) + (i))
#define LD8(p, i) vload8(0, (p) + (i))
#define ST4(p, i, v) vstore4((v), 0, (p) + (i))
#define ST8(p, i, v) vstore8((v), 0, (p) + (i))
#define A_ZERO ((half)0.0h)
#define CONVERT_A(x) ((half)(x))
#define CONVERT_A4(x) convert_half4(x)
#define CONVERT_A8(x) convert_half8(x)
#elif defined(CLSS_FP16)
typedef half T;
typedef ushort TB;
typedef float A;
typedef float4 A4;
typedef float8 A8;
#define LD(p, i) vload_half((i), (p))
#define ST(p, i, v) vstore_half_rte((v), (i), (p))
#define LD4(p, i) vload_half4(0, (p) + (i))
#define LD8(p, i) vload_half8(0, (p) + (i))
#define ST4(p, i, v) vstore_half4_rte((v), 0, (p) + (i))
#define ST8(p, i, v) vstore_half8_rte((v), 0, (p) + (i))
#define A_ZERO 0.0f
#define CONVERT_A(x) ((float)(x))
#define CONVERT_A4(x) convert_float4(x)
#define CONVERT_A8(x) convert_float8(x)
#else
typedef float T;
typedef uint TB;
typedef float A;
typedef float4 A4;
typedef float8 A8;
#define LD(p, i) ((p)[(i)])
#define ST(p, i, v) ((p)[(i)] = (v))
#define LD4(p, i) vload4(0, (p) + (i))
#define LD8(p, i) vload8(0, (p) + (i))
#define ST4(p, i, v) vstore4((v), 0, (p) + (i))
#define ST8(p, i, v) vstore8((v), 0, (p) + (i))
#define A_ZERO 0.0f
#define CONVERT_A(x) ((float)(x))
#define CONVERT_A4(x) convert_float4(x)
#define CONVERT_A8(x) convert_float8(x)
#endif

/* Fused activations, selected by -DACT=<n> where a kernel supports them.
 * The host passes alpha (leaky_relu slope) as a float argument. */
#define ACT_NONE 0
#define ACT_RELU 1
#define ACT_LEAKY_RELU 2
#define ACT_SIGMOID 3
#define ACT_TANH 4

#ifndef ACT
#define ACT ACT_NONE
#endif

/* The logistic sigmoid, in the one form every kernel uses (the conv epilogue, the gated
 * conv's gates, the LSTM cell), so that fused and unfused paths round alike. Generic in
 * the vector width. */
#define SIGMOID(x) ((A)1 / ((A)1 + exp(-(x))))

/* Generic in the vector width: works for A, A4 and A8 alike. */
/* relu/leaky_relu: NaN passes through, as in onnxruntime (fmax(NaN, 0) is 0). */
#if ACT == ACT_RELU
#define APPLY_ACT(x, alpha) (((x) < (A)0) ? (A)0 : (x))
#elif ACT == ACT_LEAKY_RELU
#define APPLY_ACT(x, alpha) (((x) < (A)0) ? (x) * (A)(alpha) : (x))
#elif ACT == ACT_SIGMOID
#define APPLY_ACT(x, alpha) SIGMOID(x)
#elif ACT == ACT_TANH
#define APPLY_ACT(x, alpha) tanh(x)
#else
#define APPLY_ACT(x, alpha) (x)
#endif

/* Raw-bit vectors for data movement (vload8/vload16 of TB). */
#if defined(CLSS_FP16) || defined(CLSS_FP16_NATIVE)
typedef ushort8 TB8;
typedef ushort16 TB16;
#else
typedef uint8 TB8;
typedef uint16 TB16;
#endif

/* Loads and stores without builtin calls in the hot loops, where the host
 * asks for them (-DCLSS_CLANG_VECTORS=1, on PoCL). PoCL 3.0
 * (pocl-binary-distribution) links its kernel library, built for haswell,
 * into kernels built for the host CPU, and LLVM does not inline across that
 * mismatch: each vload8/vload_half/mad/min becomes an out-of-line call, and a
 * call makes every live vector register (all caller-saved) spill. Clang's
 * vector extensions express the same accesses as plain loads and stores
 * (element-aligned, like vloadn). Elsewhere (other vendors, oclgrind, which
 * cannot simulate half<->float vector conversions) the common.h macros. */
#ifndef CLSS_CLANG_VECTORS
#define CLSS_CLANG_VECTORS 0
#endif
#if defined(__clang__) && CLSS_CLANG_VECTORS
#if defined(CLSS_FP16)
typedef half Th1 __attribute__((ext_vector_type(1)));
typedef half Th8 __attribute__((ext_vector_type(8), aligned(2)));
typedef float Ta1 __attribute__((ext_vector_type(1)));
#define FLD(p, i) (__builtin_convertvector(*(__global const Th1 *)((p) + (i)), Ta1).x)
#define FLD8(p, i) __builtin_convertvector(*(__global const Th8 *)((p) + (i)), A8)
#define FST8(p, i, v) (*(__global Th8 *)((p) + (i)) = __builtin_convertvector((A8)(v), Th8))
#define FST(p, i, v) (*(__global Th1 *)((p) + (i)) = __builtin_convertvector((Ta1)(v), Th1))
#else
typedef T Tv8 __attribute__((ext_vector_type(8), aligned(sizeof(T))));
#define FLD(p, i) ((A)(p)[(i)])
#define FLD8(p, i) ((A8)(*(__global const Tv8 *)((p) + (i))))
#define FST8(p, i, v) (*(__global Tv8 *)((p) + (i)) = (v))
#define FST(p, i, v) ((p)[(i)] = (T)(v))
#endif
#else
#define FLD LD
#define FLD8 LD8
#define FST8 ST8
#define FST ST
#endif

/* float8 of a float buffer (XLD8) or of a private float array (PLD8, PST8) without the
 * vload8/vstore8 calls that PoCL makes out of line (-DCLSS_CLANG_VECTORS=1, as above):
 * clang vector accesses, element-aligned as vload8's. */
#if defined(__clang__) && CLSS_CLANG_VECTORS
typedef float Fv8u __attribute__((ext_vector_type(8), aligned(4)));
#define XLD8(p) ((float8)(*(__global const Fv8u *)(p)))
#define PLD8(a) ((float8)(*(__private const Fv8u *)(a)))
#define PST8(a, v) (*(__private Fv8u *)(a) = (v))
#else
#define XLD8(p) vload8(0, (p))
#define PLD8(a) vload8(0, (a))
#define PST8(a, v) vstore8((v), 0, (a))
#endif

/* 8 elements' bits (TB8) of a buffer, for data movement: clang vector accesses where the
 * host asks for them (PoCL, as above), else vload8/vstore8. */
#if defined(__clang__) && CLSS_CLANG_VECTORS
typedef TB TBv8 __attribute__((ext_vector_type(8), aligned(sizeof(TB))));
#define TB_LD8(p) ((TB8)(*(__global const TBv8 *)(p)))
#define TB_ST8(p, v) (*(__global TBv8 *)(p) = (TBv8)(v))
#else
#define TB_LD8(p) vload8(0, (p))
#define TB_ST8(p, v) vstore8((TB8)(v), 0, (p))
#endif

/* Weights (conv, mlp): in fp16 storage mode the host hands them over as float,
 * rounded to half (conv.cl's weights_to_float once per call, mlp's packing once
 * per network), so hot loops broadcast them with one load instead of a load, a
 * half->float conversion and a shuffle. */
#if defined(CLSS_FP16)
typedef float TW;
#define LDW(p, i) ((p)[(i)])
#else
typedef T TW;
#define LDW FLD
#endif

#endif /* CLSS_COMMON_H */

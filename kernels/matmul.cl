/* Matrix products of two run-time tensors: ONNX MatMul (batched, broadcasting) and Gemm
 * (alpha, beta, transposes, C broadcast), as attention uses them (Q K^T, softmax(.) V).
 * A MatMul or Gemm with a constant B never comes here: clss.Model lowers it to a 1x1
 * convolution (clss/model/passes.py), which has the conv family's fast paths.
 *
 *   out[b, m, n] = alpha * sum_k A[b, m, k] * B[b, k, n] + beta * C[m, n]
 *
 * Every operand is read through element strides, so a transposed or broadcast operand
 * needs no copy: A at a_b0*b0 + a_b1*b1 + a_m*m + a_k*k, B likewise, C at c_m*m + c_n*n
 * (0 along a broadcast axis). Up to two batch dimensions [B0, B1].
 *
 * A work-item computes a TM x TN tile of one batch (TM rows of A times TN columns of B:
 * TM + TN loads per TM * TN multiply-adds), NDRange (ceil(N / TN), ceil(M / TM), B0 * B1).
 * Edge tiles clamp their reads and skip their stores.
 *
 * Build options:
 *   -DTM=n, -DTN=n   the register tile (default 4 x 4)
 *   -DHAS_C=0|1      add beta * C
 */
#include "common.h"

#ifndef TM
#define TM 4
#endif
#ifndef TN
#define TN 4
#endif
#ifndef HAS_C
#define HAS_C 0
#endif

/** @param[in]  a       A
 *  @param[in]  b       B
 *  @param[in]  c       C (read with -DHAS_C=1)
 *  @param[out] out     [B0, B1, M, N] the product (contiguous)
 *  @param[in]  M, N, K  the product's sizes
 *  @param[in]  B1      the second batch dimension (B0 * B1 is NDRange dimension 2)
 *  @param[in]  a_b0, a_b1, a_m, a_k  A's element strides (0 where A broadcasts)
 *  @param[in]  b_b0, b_b1, b_k, b_n  B's element strides
 *  @param[in]  c_m, c_n  C's element strides
 *  @param[in]  alpha, beta  Gemm's scales (1 and 0 for MatMul)
 *  @note -DTM=n, -DTN=n: the register tile; -DHAS_C=0|1
 *  @note -DCLSS_FP16 / -DCLSS_FP16_NATIVE: the storage precision (common.h); T and TB follow it
 */
__kernel void matmul(__global const T *a, __global const T *b, __global const T *c, __global T *out,
                     int M, int N, int K, int B1, long a_b0, long a_b1, long a_m, long a_k,
                     long b_b0, long b_b1, long b_k, long b_n, long c_m, long c_n,
                     float alpha, float beta)
{
    const int n0 = get_global_id(0) * TN, m0 = get_global_id(1) * TM, z = get_global_id(2);
    if (n0 >= N || m0 >= M) return;
    const int z0 = z / B1, z1 = z % B1;
    __global const T *pa = a + z0 * a_b0 + z1 * a_b1;
    __global const T *pb = b + z0 * b_b0 + z1 * b_b1;
    long ra[TM], cb[TN];
    for (int i = 0; i < TM; ++i)
        ra[i] = (long)min(m0 + i, M - 1) * a_m;
    for (int j = 0; j < TN; ++j)
        cb[j] = (long)min(n0 + j, N - 1) * b_n;
    float acc[TM][TN];
    for (int i = 0; i < TM; ++i)
        for (int j = 0; j < TN; ++j)
            acc[i][j] = 0.0f;
    for (int k = 0; k < K; ++k) {
        float av[TM], bv[TN];
        for (int i = 0; i < TM; ++i)
            av[i] = (float)LD(pa, ra[i] + k * a_k);
        for (int j = 0; j < TN; ++j)
            bv[j] = (float)LD(pb, cb[j] + k * b_k);
        for (int i = 0; i < TM; ++i)
            for (int j = 0; j < TN; ++j)
                acc[i][j] = fma(av[i], bv[j], acc[i][j]);
    }
    __global T *po = out + (long)z * M * N;
    for (int i = 0; i < TM; ++i) {
        const int m = m0 + i;
        if (m >= M) break;
        for (int j = 0; j < TN; ++j) {
            const int n = n0 + j;
            if (n >= N) break;
            float v = alpha * acc[i][j];
#if HAS_C
            v += beta * (float)LD(c, m * c_m + n * c_n);
#endif
            ST(po, (long)m * N + n, v);
        }
    }
}

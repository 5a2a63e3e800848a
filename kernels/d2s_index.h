/* d2s_index.h: where a conv output lands when a DepthToSpace is fused into the conv's store
 * (ONNX DepthToSpace, blocksize r = -DD2S, -DD2S_CRD=1 for mode CRD, else DCR). Conv output
 * channel c of image n at (oy, ox), one of C channels over Ho x Wo, is element
 * [n][c'][oy r + i][ox r + j] of the [N][C / r^2][Ho r][Wo r] tensor, where
 *   CRD: c = c' r^2 + i r + j        DCR: c = (i r + j) C / r^2 + c'
 * A pixel shuffle (torch's PixelShuffle) is CRD. Consecutive ox land r elements apart. */
#ifndef CLSS_D2S_INDEX_H
#define CLSS_D2S_INDEX_H

#ifndef D2S
#define D2S 0
#endif
#ifndef D2S_CRD
#define D2S_CRD 1
#endif

#if D2S
inline long d2s_at(int n, int c, int oy, int ox, int C, int Ho, int Wo)
{
    const int r = D2S, cq = C / (D2S * D2S);
#if D2S_CRD
    const int cp = c / (r * r), i = (c / r) % r, j = c % r;
#else
    const int cp = c % cq, i = (c / cq) / r, j = (c / cq) % r;
#endif
    return (((long)n * cq + cp) * Ho * r + (long)oy * r + i) * ((long)Wo * r) + (long)ox * r + j;
}
#endif

#endif

"""Image quality of supersampled output against a reference: PSNR, SSIM, temporal
PSNR, FLIP, temporal profiles and labelled side-by-side pictures.

All metrics compare *display* values: both images go through `clss.io.tonemap`
(exposure, ACES fit, sRGB OETF) to [0, 1] first, so that HDR highlights do not
dominate the error and the numbers track what a viewer sees. Pass `tonemapped=True`
when the images are already display values in [0, 1].
"""
from __future__ import annotations

import os

import numpy as np

from . import io as cio


def _display(img, exposure, tonemapped):
    a = np.asarray(img, np.float32)
    if tonemapped:
        return np.clip(np.nan_to_num(a), 0, 1)
    return cio.tonemap(a, exposure)


def _check_pair(test, ref):
    if np.shape(test) != np.shape(ref):
        raise ValueError(f"image shapes differ: {np.shape(test)} vs reference {np.shape(ref)}")


def psnr(test, ref, exposure=1.0, tonemapped=False):
    """PSNR in dB (peak 1) of tone-mapped `test` against tone-mapped `ref`."""
    from skimage.metrics import peak_signal_noise_ratio
    _check_pair(test, ref)
    a, b = _display(test, exposure, tonemapped), _display(ref, exposure, tonemapped)
    if np.array_equal(a, b):
        return float("inf")
    return float(peak_signal_noise_ratio(b, a, data_range=1.0))


def ssim(test, ref, exposure=1.0, tonemapped=False):
    """SSIM (scikit-image defaults: 7x7 uniform window, per channel, averaged) of
    tone-mapped images."""
    from skimage.metrics import structural_similarity
    _check_pair(test, ref)
    a, b = _display(test, exposure, tonemapped), _display(ref, exposure, tonemapped)
    win = min(7, min(a.shape[:2]) // 2 * 2 - 1)
    if win < 3:
        raise ValueError(f"image {a.shape[:2]} too small for SSIM")
    return float(structural_similarity(b, a, data_range=1.0, win_size=win,
                                       channel_axis=-1 if a.ndim == 3 else None))


class TemporalPSNR:
    """Running temporal PSNR (see `temporal_psnr`), fed one frame at a time so that a
    long sequence need not be held in memory. `add(test, ref)` compares the step from
    the previous frame; `cut()` forgets the previous frame (a camera cut, or frames
    left out of the score), so no difference is taken across it. Frames are display
    values in [0, 1] (pass them through `display` first)."""

    def __init__(self):
        self.se, self.n = 0.0, 0
        self._prev = None

    def cut(self):
        self._prev = None

    def add(self, test, ref):
        _check_pair(test, ref)
        a, b = np.asarray(test, np.float64), np.asarray(ref, np.float64)
        if self._prev is not None:
            pa, pb = self._prev
            if pa.shape != a.shape:
                raise ValueError(f"frame shape changed: {pa.shape} -> {a.shape}")
            d = (a - pa) - (b - pb)
            self.se += float(np.sum(d * d))
            self.n += d.size
        self._prev = (a, b)

    @property
    def pairs(self):
        return self.n

    def value(self):
        """dB; inf when the differences match exactly; nan before any pair."""
        if self.n == 0:
            return float("nan")
        mse = self.se / self.n
        return float("inf") if mse == 0 else float(10 * np.log10(1.0 / mse))


def temporal_psnr(tests, refs, exposure=1.0, tonemapped=False):
    """PSNR (peak 1) of the frame-to-frame differences: test[t] - test[t-1] against
    ref[t] - ref[t-1], over all t >= 1 of the tone-mapped sequences (one mean squared
    error over every pixel of every difference). Flicker that the reference does not
    have lowers it even when each frame's PSNR is good."""
    if len(tests) != len(refs) or len(tests) < 2:
        raise ValueError("temporal_psnr needs two sequences of equal length >= 2")
    acc = TemporalPSNR()
    for t, r in zip(tests, refs):
        acc.add(_display(t, exposure, tonemapped), _display(r, exposure, tonemapped))
    return acc.value()


def flip(test, ref, exposure=1.0, tonemapped=False, error_map=False):
    """Mean LDR-FLIP error (NVIDIA's perceptual difference, `flip-evaluator` package;
    0 = identical, 1 = maximal; default viewing condition, 67 pixels per degree) of the
    tone-mapped sRGB display images, the same display values as `psnr` and `ssim`.
    LDR-FLIP rather than HDR-FLIP so that all metrics judge one tone mapping (HDR-FLIP
    would average over exposures of its own choosing). With `error_map=True`, returns
    (mean, per-pixel error map h x w)."""
    try:
        import flip_evaluator
    except ImportError:
        raise RuntimeError("FLIP needs the flip-evaluator package (pip install "
                           "flip-evaluator)") from None
    _check_pair(test, ref)
    a, b = _display(test, exposure, tonemapped), _display(ref, exposure, tonemapped)
    if a.ndim != 3 or a.shape[2] != 3:
        raise ValueError(f"FLIP needs h x w x 3 colour images, got shape {a.shape}")
    emap, mean, _ = flip_evaluator.evaluate(np.ascontiguousarray(b), np.ascontiguousarray(a),
                                            "LDR", inputsRGB=True, applyMagma=False)
    return (float(mean), np.asarray(emap)[..., 0]) if error_map else float(mean)


def display(img, exposure=1.0):
    """The display values every metric compares: `clss.io.tonemap` of a linear image
    (h x w [x 3]) to [0, 1]."""
    return _display(img, exposure, False)


def sequence_metrics(tests, refs, exposure=1.0, tonemapped=False, skip=0):
    """{"psnr": [...], "ssim": [...], "psnr_mean", "ssim_mean", "tpsnr"} over frames
    [skip:] (skip the first frames while the history warms up)."""
    tests, refs = list(tests)[skip:], list(refs)[skip:]
    p = [psnr(t, r, exposure, tonemapped) for t, r in zip(tests, refs)]
    s = [ssim(t, r, exposure, tonemapped) for t, r in zip(tests, refs)]
    out = {"psnr": p, "ssim": s, "psnr_mean": float(np.mean(p)), "ssim_mean": float(np.mean(s))}
    if len(tests) >= 2:
        out["tpsnr"] = temporal_psnr(tests, refs, exposure, tonemapped)
    return out


# ---------------------------------------------------------------- pictures

def temporal_profile(frames, row=None, col=None, span=None, repeat=4):
    """One scanline over time, as the paper's Figs. 1, 5, 8: the vertical axis runs
    along the line, the horizontal axis is time (each frame `repeat` pixels wide).

    Give `row` (a horizontal line; `span` = (x0, x1)) or `col` (a vertical line;
    `span` = (y0, y1)). Frames are not motion-compensated, so keep the camera still or
    read slanted streaks as motion; flicker shows as broken, noisy streaks."""
    if (row is None) == (col is None):
        raise ValueError("give exactly one of row= or col=")
    lines = []
    for f in frames:
        a = np.asarray(f, np.float32)
        line = a[row, :] if row is not None else a[:, col]
        if span is not None:
            line = line[span[0]:span[1]]
        lines.append(line)
    prof = np.stack(lines, 1)                  # (line length, T, ...)
    return np.repeat(prof, repeat, 1)


_FONT = None


def _font():
    global _FONT
    if _FONT is None:
        try:
            import matplotlib
            from matplotlib.ft2font import FT2Font
            path = os.path.join(matplotlib.get_data_path(), "fonts", "ttf", "DejaVuSans.ttf")
            _FONT = FT2Font(path)
        except Exception:          # no matplotlib or no font: labels are left out
            _FONT = False
    return _FONT


def text_bitmap(text, height=14):
    """Grey coverage (h x w float in [0,1]) of `text` in DejaVu Sans about `height`
    pixels tall, or None when no font is available."""
    f = _font()
    if not f or not text:
        return None
    f.set_size(height * 0.72, 100)          # points at 100 dpi -> about `height` px
    f.set_text(text, 0.0)
    f.draw_glyphs_to_bitmap()
    return np.asarray(f.get_image(), np.float32) / 255.0


def crop_zoom(img, crop=None, zoom=1):
    """img[y0:y1, x0:x1] (crop = (y0, y1, x0, x1)), enlarged `zoom` times by pixel
    repetition so that aliasing stays visible."""
    a = np.asarray(img)
    if crop is not None:
        y0, y1, x0, x1 = crop
        a = a[y0:y1, x0:x1]
    if zoom != 1:
        a = np.repeat(np.repeat(a, zoom, 0), zoom, 1)
    return a


def side_by_side(images, labels=None, exposure=1.0, tonemapped=False, gap=4, band=20,
                 crop=None, zoom=1, background=0.1):
    """Display image (h x W x 3 in [0, 1]) of the images side by side, each under a
    label band. Images are tone-mapped unless `tonemapped`. Images smaller than the
    tallest one by an integer factor (a render-resolution frame next to output-resolution
    ones) are enlarged by pixel repetition first; then `crop` = (y0, y1, x0, x1) in the
    tallest image's pixels and `zoom` apply to all."""
    imgs = []
    for im in images:
        a = _display(im, exposure, tonemapped)
        if a.ndim == 2:
            a = a[..., None]
        imgs.append(np.repeat(a, 3, -1) if a.shape[2] == 1 else a[..., :3])
    h = max(a.shape[0] for a in imgs)
    for i, a in enumerate(imgs):
        if a.shape[0] != h:
            f = h // a.shape[0]
            if f * a.shape[0] != h:
                raise ValueError(f"image {i}: height {a.shape[0]} does not divide {h}")
            imgs[i] = np.repeat(np.repeat(a, f, 0), f, 1)
    imgs = [crop_zoom(a, crop, zoom) for a in imgs]
    h = max(a.shape[0] for a in imgs)
    band = band if labels else 0
    W = sum(a.shape[1] for a in imgs) + gap * (len(imgs) - 1)
    canvas = np.full((h + band, W, 3), background, np.float32)
    x = 0
    for i, a in enumerate(imgs):
        canvas[band:band + a.shape[0], x:x + a.shape[1]] = a
        if labels and i < len(labels):
            t = text_bitmap(str(labels[i]), max(band - 6, 6))
            if t is not None:
                th, tw = min(t.shape[0], band), min(t.shape[1], max(a.shape[1] - 4, 0))
                y0 = (band - th) // 2
                reg = canvas[y0:y0 + th, x + 4:x + 4 + tw]
                reg += (1 - reg) * t[:th, :tw, None]
        x += a.shape[1] + gap
    return canvas


def save_side_by_side(path, images, labels=None, **kw):
    """`side_by_side` written as an 8-bit PNG through clss.io (atomic)."""
    cio.write_png_ldr(path, side_by_side(images, labels, **kw))
    return path


def save_temporal_profiles(path, sequences, labels=None, row=None, col=None, span=None,
                           repeat=4, exposure=1.0, **kw):
    """Temporal profiles of several sequences (e.g. bicubic, ours, reference) side by
    side in one PNG."""
    profs = [temporal_profile(s, row=row, col=col, span=span, repeat=repeat) for s in sequences]
    return save_side_by_side(path, profs, labels, exposure=exposure, **kw)


def nearest(img, H, W):
    """Render-resolution image enlarged to H x W by nearest neighbour (any scale): how the
    input looks at output size, the first panel of the side-by-sides."""
    h, w = img.shape[:2]
    iy = np.minimum(((np.arange(H) + 0.5) * h / H).astype(np.int64), h - 1)
    ix = np.minimum(((np.arange(W) + 0.5) * w / W).astype(np.int64), w - 1)
    return img[iy][:, ix]


# Relative view-depth change beyond which a reprojected pixel counts as disoccluded: what
# the history shows there is another surface (CLSS's rule mode rejects at the same 10 %).
DISOCCLUSION_THRESHOLD = 0.1


def disocclusion_mask(depth_prev, depth, motion, out_hw, threshold=DISOCCLUSION_THRESHOLD):
    """H x W bool: output pixels whose render pixel, reprojected to the previous frame
    (p + motion, nearest sample), lands off screen or on a surface whose view depth
    differs by more than `threshold` (relative). Depth is reversed-Z (depth = near / z,
    so view depth ratios are depth ratios; 0 is the sky). These are the pixels where a
    history can only ghost: the error there is the ghosting the eval reports."""
    h, w = depth.shape
    ii, jj = np.meshgrid(np.arange(h), np.arange(w), indexing="ij")
    pi = np.rint(ii + motion[..., 1]).astype(np.int64)
    pj = np.rint(jj + motion[..., 0]).astype(np.int64)
    off = (pi < 0) | (pi >= h) | (pj < 0) | (pj >= w)
    prev = depth_prev[np.clip(pi, 0, h - 1), np.clip(pj, 0, w - 1)].astype(np.float64)
    cur = depth.astype(np.float64)
    # |z - z_prev| / z with z = near / depth: |depth / depth_prev - 1|
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = np.abs(cur / prev - 1.0)
    sky_cur, sky_prev = cur <= 0, prev <= 0
    changed = np.where(sky_cur | sky_prev, sky_cur != sky_prev, rel > threshold)
    return nearest(off | changed, *out_hw)


def masked_psnr_terms(test_display, ref_display, mask):
    """(sum of squared errors, count) of display values over `mask`'s pixels (all three
    channels): summed over a sequence, then turned into one PSNR."""
    if not mask.any():
        return 0.0, 0
    d = (test_display[mask] - ref_display[mask]).astype(np.float64)
    return float(np.sum(d * d)), int(d.size)

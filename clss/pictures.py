"""Pictures a visitor reads at a glance: a labelled grid of tiles, the window where a
method errs most (the region worth a zoomed inset), a whole-frame overview with that
window marked, and a short animated GIF. `clss demo` draws its pictures with these; the
labels and the tone mapping are clss.metrics' (`text_bitmap`, `display`).

Everything here takes display values in [0, 1] (h x w x 3 float), so a caller tone-maps
once. Widths are chosen by the caller (`tile_width`): a grid meant for a 1200 px page
stays 1200 px wide however many methods it holds, by adding rows, not columns."""
from __future__ import annotations

import os

import numpy as np

from . import metrics

PAGE_WIDTH = 1200       # what a README or an issue shows a picture at
MARK = (1.0, 0.25, 0.1)  # the colour of the box that marks the inset on the overview


def tile_width(cols: int, gap: int = 6, page: int = PAGE_WIDTH) -> int:
    """The width of each of `cols` tiles that fill `page` pixels with `gap` between."""
    return (page - gap * (cols - 1)) // cols


def error_map(test, ref):
    """Per-pixel error of display images: the mean absolute difference over channels."""
    return np.abs(np.asarray(test, np.float32) - np.asarray(ref, np.float32)).mean(-1)


def hardest_box(err, h: int, w: int):
    """(y0, y1, x0, x1) of the h x w window with the largest summed error (an integral
    image, so every window is scored): where the zoomed inset shows what differs."""
    H, W = err.shape
    h, w = min(h, H), min(w, W)
    s = np.zeros((H + 1, W + 1))
    s[1:, 1:] = np.cumsum(np.cumsum(err, 0), 1)
    win = s[h:, w:] - s[:-h, w:] - s[h:, :-w] + s[:-h, :-w]
    y0, x0 = np.unravel_index(int(np.argmax(win)), win.shape)
    return int(y0), int(y0 + h), int(x0), int(x0 + w)


def zoom(img, box, factor: int):
    """img[box] enlarged `factor` times by pixel repetition, so that aliasing stays
    visible rather than smoothed over."""
    return metrics.crop_zoom(img, box, factor)


def overview(img, width: int, box=None, line: int = 2):
    """The whole image shrunk to at most `width` pixels (block means of an integer
    factor), with `box` (in the image's pixels) outlined in MARK."""
    a = np.asarray(img, np.float32)
    k = max(1, -(-a.shape[1] // width))
    h, w = a.shape[0] // k, a.shape[1] // k
    small = a[:h * k, :w * k].reshape(h, k, w, k, -1).mean((1, 3))
    if box is not None:
        y0, y1, x0, x1 = (min(max(v // k, 0), n - 1) for v, n in zip(box, (h, h, w, w)))
        for ys, xs in ((slice(y0, y0 + line), slice(x0, x1 + 1)),
                       (slice(y1 - line + 1, y1 + 1), slice(x0, x1 + 1)),
                       (slice(y0, y1 + 1), slice(x0, x0 + line)),
                       (slice(y0, y1 + 1), slice(x1 - line + 1, x1 + 1))):
            small[ys, xs] = MARK
    return small


def grid(tiles, labels, cols: int, gap: int = 6, band: int = 24, background: float = 0.1):
    """Tiles (display images, any sizes) in rows of `cols`, each under its label band;
    a cell is as large as the largest tile. Returns the display image."""
    th = max(t.shape[0] for t in tiles)
    tw = max(t.shape[1] for t in tiles)
    rows = -(-len(tiles) // cols)
    ncols = min(cols, len(tiles))
    canvas = np.full((rows * (th + band) + gap * (rows - 1), ncols * tw + gap * (ncols - 1), 3),
                     background, np.float32)
    for i, (t, label) in enumerate(zip(tiles, labels)):
        y, x = (i // cols) * (th + band + gap), (i % cols) * (tw + gap)
        canvas[y + band:y + band + t.shape[0], x:x + t.shape[1]] = t[..., :3]
        size = band - 8
        text = metrics.text_bitmap(str(label), size)
        while text is not None and text.shape[1] > tw - 4 and size > 6:    # smaller, not cut
            size -= 1
            text = metrics.text_bitmap(str(label), size)
        if text is not None:
            h, w = min(text.shape[0], band), min(text.shape[1], tw - 4)
            reg = canvas[y + (band - h) // 2:y + (band - h) // 2 + h, x + 2:x + 2 + w]
            reg += (1 - reg) * text[:h, :w, None]
    return canvas


def save_gif(path, frames, fps: float = 8.0):
    """An animated GIF that loops, one subimage per display frame, through
    OpenImageIO (already a dependency: no video encoder is needed). Written to a
    temporary name, then renamed, as clss.io writes every file."""
    import OpenImageIO as oiio
    frames = [np.ascontiguousarray((np.clip(f, 0, 1) * 255 + 0.5).astype(np.uint8))
              for f in frames]
    h, w = frames[0].shape[:2]
    tmp = f"{path}.tmp{os.getpid()}.gif"
    out = oiio.ImageOutput.create(tmp)
    specs = []
    for _ in frames:
        spec = oiio.ImageSpec(w, h, 3, "uint8")
        spec.attribute("FramesPerSecond", oiio.TypeDesc("rational"), (int(round(fps)), 1))
        spec.attribute("oiio:LoopCount", 0)
        specs.append(spec)
    try:
        if out is None or not out.open(tmp, specs):
            raise OSError(f"{path}: cannot write a GIF ({oiio.geterror()})")
        for i, f in enumerate(frames):
            if i and not out.open(tmp, specs[i], "AppendSubimage"):
                raise OSError(f"{path}: {out.geterror()}")
            out.write_image(f)
        out.close()
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)
    return path

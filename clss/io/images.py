"""One file at a time, through OpenImageIO: EXR in and out, 8-bit PNG out (tone-mapped by
`clss.io.tonemap`, or already in display space), and JSON out. Every write goes to a
temporary file in the same directory and is renamed into place, so a file already
written stays valid when a later write fails or is interrupted."""
from __future__ import annotations

import json
import os
import tempfile

import numpy as np

from ..filemode import new_file_mode
from .errors import InputError
from .tonemap import to_uint8

try:
    import OpenImageIO as oiio
except ImportError:     # pragma: no cover - OpenImageIO is a hard dependency
    oiio = None


def _require_oiio():
    if oiio is None:
        raise RuntimeError("OpenImageIO (python module OpenImageIO) is not installed")


def _atomic_write(path, write):
    """Call write(tmp_path) then rename onto path. The temporary name keeps the
    extension, which is how OpenImageIO picks the format. The file gets the mode a
    plain open() would give (the umask's), not mkstemp's private 0600."""
    path = os.fspath(path)
    d, base = os.path.split(os.path.abspath(path))
    os.makedirs(d, exist_ok=True)
    ext = os.path.splitext(base)[1]
    fd, tmp = tempfile.mkstemp(prefix="." + base + ".", suffix=".tmp" + ext, dir=d)
    os.close(fd)
    try:
        write(tmp)
        os.chmod(tmp, new_file_mode())      # after writing: a writer may recreate the file
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def _write_oiio(path, pixels, fmt, names=None, channelformats=None):
    def write(tmp):
        h, w, c = pixels.shape
        spec = oiio.ImageSpec(w, h, c, fmt)
        if names is not None:
            spec.channelnames = tuple(names)
        if channelformats is not None:
            spec.channelformats = tuple(oiio.TypeDesc(f) for f in channelformats)
        if fmt in ("half", "float"):
            spec.attribute("compression", "zip")
        out = oiio.ImageOutput.create(tmp)
        if out is None:
            raise OSError(f"{path}: cannot create ({oiio.geterror()})")
        try:
            if not out.open(tmp, spec) or not out.write_image(pixels):
                raise OSError(f"{path}: cannot write ({out.geterror()})")
        finally:
            out.close()
    _atomic_write(path, write)


def default_channel_names(n):
    return {1: ["Y"], 2: ["x", "y"], 3: ["R", "G", "B"], 4: ["R", "G", "B", "A"]}.get(
        n, [f"c{i}" for i in range(n)])


def write_exr(path, image, half=True, channel_names=None):
    """Write an h x w or h x w x c image as EXR. `half`: True/False for all channels,
    or one bool per channel (e.g. half colour, float depth). Channel names default to
    Y / x,y / R,G,B / R,G,B,A."""
    _require_oiio()
    a = np.asarray(image, np.float32)
    if a.ndim == 2:
        a = a[..., None]
    if a.ndim != 3:
        raise ValueError(f"{path}: expected an h x w or h x w x c image, got shape {a.shape}")
    c = a.shape[2]
    names = list(channel_names) if channel_names is not None else default_channel_names(c)
    if len(names) != c:
        raise ValueError(f"{path}: {len(names)} channel names for {c} channels")
    halves = [bool(half)] * c if isinstance(half, (bool, np.bool_, int)) else list(half)
    if len(halves) != c:
        raise ValueError(f"{path}: {len(halves)} half flags for {c} channels")
    fmts = ["half" if h else "float" for h in halves]
    _write_oiio(path, np.ascontiguousarray(a), "float" if "float" in fmts else "half",
                names, fmts if len(set(fmts)) > 1 else None)


def write_png(path, linear_rgb, exposure=1.0):
    """8-bit sRGB PNG of a linear image (h x w or h x w x 3) through `tonemap`."""
    _require_oiio()
    a = np.asarray(linear_rgb, np.float32)
    if a.ndim == 2:
        a = np.repeat(a[..., None], 3, -1)
    if a.ndim != 3 or a.shape[2] not in (1, 3):
        raise ValueError(f"{path}: expected h x w or h x w x 3, got shape {a.shape}")
    _write_oiio(path, np.ascontiguousarray(to_uint8(a, exposure)), "uint8")


def write_png_ldr(path, display_rgb):
    """8-bit PNG of values already in display space [0, 1] (no tone mapping)."""
    _require_oiio()
    a = np.clip(np.nan_to_num(np.asarray(display_rgb, np.float32)), 0, 1)
    if a.ndim == 2:
        a = np.repeat(a[..., None], 3, -1)
    _write_oiio(path, np.ascontiguousarray((a * 255 + 0.5).astype(np.uint8)), "uint8")


def write_json(path, obj):
    """JSON file, written atomically (a temporary name, then renamed)."""
    def dump(tmp):
        with open(tmp, "w") as fh:
            json.dump(obj, fh, indent=1)
    _atomic_write(path, dump)


def read_header(path):
    """(width, height, channel names) of an image file from its header alone, without
    its pixels (clss batch checks finished frames this way); InputError if unreadable."""
    _require_oiio()
    path = os.fspath(path)
    inp = oiio.ImageInput.open(path)
    if inp is None:
        raise InputError(f"{path}: cannot read ({oiio.geterror()})")
    try:
        spec = inp.spec()
        return spec.full_width, spec.full_height, list(spec.channelnames)
    finally:
        inp.close()


def read_exr(path):
    """(pixels h x w x c float32 over the display window, channel names)."""
    _require_oiio()
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise InputError(f"{path}: no such file")
    inp = oiio.ImageInput.open(path)
    if inp is None:
        raise InputError(f"{path}: cannot read ({oiio.geterror()})")
    try:
        spec = inp.spec()
        data = inp.read_image(0, 0, 0, spec.nchannels, "float")
        if data is None:
            raise InputError(f"{path}: cannot read pixels ({inp.geterror()})")
    finally:
        inp.close()
    data = np.asarray(data, np.float32).reshape(spec.height, spec.width, spec.nchannels)
    names = list(spec.channelnames)
    fw, fh = spec.full_width, spec.full_height
    if (spec.x, spec.y, spec.width, spec.height) == (spec.full_x, spec.full_y, fw, fh):
        return data, names
    full = np.zeros((fh, fw, spec.nchannels), np.float32)
    # Data window relative to the display window, clipped to it.
    x0, y0 = spec.x - spec.full_x, spec.y - spec.full_y
    cx0, cy0 = max(x0, 0), max(y0, 0)
    cx1, cy1 = min(x0 + spec.width, fw), min(y0 + spec.height, fh)
    if cx1 > cx0 and cy1 > cy0:
        full[cy0:cy1, cx0:cx1] = data[cy0 - y0:cy1 - y0, cx0 - x0:cx1 - x0]
    return full, names

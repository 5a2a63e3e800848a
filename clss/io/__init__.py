"""Frame sequences in and out: EXR through OpenImageIO, tone-mapped PNG, jitter sidecars.

Reading (`read_sequence`) accepts
  * one multichannel EXR per frame: a directory, a glob (``shots/*.exr``) or a numbered
    pattern (``shot.%04d.exr``, ``shot.####.exr``); colour, depth and motion are found
    by channel name (`CHANNEL_CANDIDATES`) unless `channels=` names them;
  * one file per buffer: ``{"color": "color.%04d.exr", "depth": "depth.%04d.exr",
    "motion": "motion.%04d.exr"}`` (optionally "reference"); a directory holding
    ``color.*.exr`` / ``depth.*.exr`` / ``motion.*.exr`` is recognised as this layout.
Optional G-buffers (`clss.pipeline.contract.GBUFFERS`: albedo, normal at render size;
albedo_hr, depth_hr, normal_hr at output size) come as channels of the frame file
(render-size ones; `GBUFFER_CANDIDATES` lists the names tried, `channels=` names others)
or as per-buffer files ``<name>.NNNN.exr`` beside the frames (``albedo.0003.exr``,
``depth_hr.0003.exr``; also ``gbuffers={name: pattern}`` or the per-buffer `source`
dict). Frames expose those they have as `Frame.gbuffers` ({name: array}); a G-buffer
the sequence lacks is not an error here (a method that needs it says so).
Pixels outside an EXR's data window are 0; the data window is placed inside the display
window. Jitter comes from a sidecar (``jitter.json`` or ``jitter.csv`` next to the
frames), an explicit file or array, or the Halton(2,3) sequence (`jitter="halton"`
with `scale`). No unit conversion happens here: motion and depth are returned as stored
(the pipeline's `motion_scale` / `depth_inverted` describe them).

Every failure to read raises `InputError` (a ValueError) naming the file, and the
channel or buffer where one is at fault. Writes go to a temporary file in the same
directory and are renamed into place, so frames already written stay valid.

One module per job, each importing only those before it here:
  errors.py     `InputError`
  frame.py      `Frame`: one frame's buffers (what a sequence gives and the scene renders)
  tonemap.py    linear HDR -> display values (`tonemap`, `to_uint8`)
  images.py     one file at a time: `read_exr`, `read_header`, `write_exr`, `write_png`,
                `write_png_ldr`, `write_json`, the atomic write they share
  channels.py   which channels hold which buffer (`CHANNEL_CANDIDATES`, `check_channels`,
                `read_frame`)
  discovery.py  which files are the frames (directory layouts, globs, numbered patterns,
                per-buffer G-buffer files)
  jitter.py     the jitter sidecars (`SIDECARS`), explicit jitter, Halton
  sequence.py   `read_sequence` / `FrameSequence`, and `write_sample_sequence`
Everything a caller uses is importable from `clss.io` itself (below).
"""
from __future__ import annotations

from ..filemode import current_umask, new_file_mode  # also clss.io API, as before the split
from .channels import (BUFFER_CHANNELS, CHANNEL_CANDIDATES, GBUFFER_CANDIDATES,
                       SINGLE_BUFFER_CANDIDATES, check_channels, read_frame)
from .errors import InputError
from .frame import Frame
from .images import (_atomic_write, default_channel_names, read_exr, read_header, write_exr,
                     write_json, write_png, write_png_ldr)
from .jitter import SIDECARS
from .sequence import FrameSequence, read_sequence, write_sample_sequence
from .tonemap import to_uint8, tonemap

__all__ = ["BUFFER_CHANNELS", "CHANNEL_CANDIDATES", "GBUFFER_CANDIDATES",
           "SINGLE_BUFFER_CANDIDATES", "SIDECARS", "Frame", "FrameSequence", "InputError",
           "check_channels", "current_umask", "default_channel_names", "new_file_mode",
           "read_exr", "read_frame", "read_header", "read_sequence", "to_uint8", "tonemap",
           "write_exr", "write_json", "write_png", "write_png_ldr", "write_sample_sequence"]
# `_atomic_write` is imported above for tests/test_io.py, which checks it directly.

"""What `clss batch` keeps beside each sequence's frames so that a killed batch resumes:
the settings the frames are made with (batch.json) and a journal of the frames whose
files are all written (batch.frames.jsonl: one line per frame, each file with its size).

A frame counts as finished when the journal lists it, each of its files still has the
size it was written with, and OpenImageIO reads the header of its frame.* files at the
sequence's output size. Anything else is made again: a frame never journalled (the run
was killed between its last file and its journal line), a file cut short or replaced,
a journal line cut short by the kill. clss.io writes every file to a temporary name
and renames it into place, so a killed run leaves no partial file under a frame's name;
the temporaries it leaves are removed here."""
from __future__ import annotations

import json
import os

from .args import UsageError, prepare_output_dir, start_output

SETTINGS = "batch.json"
JOURNAL = "batch.frames.jsonl"
# clss.io's temporary names: ".<file name>.<random>.tmp<ext>"
TEMPORARIES = (".*.tmp*", "debug/.*.tmp*")

# Options that do not change what a frame holds, so a resumed run may change them (the
# device may too: the same device gives bit-identical frames, another one may differ in
# the last bits, see docs/batch.md).
NEUTRAL = ("inputs", "out", "overwrite", "device", "frames", "ray_address")


def settings_of(args: dict) -> dict:
    """The options a sequence's frames depend on, as JSON gives them back."""
    return json.loads(json.dumps({k: v for k, v in sorted(args.items()) if k not in NEUTRAL}))


def _flag(key: str) -> str:
    return "--" + key.replace("_", "-")


class Journal:
    """The settings and journal of one sequence's output directory."""

    def __init__(self, directory: str):
        self.dir = directory

    def open(self, settings: dict, overwrite: bool, inputs, output_hw, outputs=()) -> set:
        """Check the directory for this run and return the numbers of the frames already
        finished there. Refused (a UsageError naming the flag): a directory that holds the
        inputs or cannot be written (as `clss upscale -o`); one holding frames made with
        other settings, or files that are not a batch's, unless `overwrite`, which
        removes the previous output (`outputs`: its glob patterns) and starts again."""
        stale = prepare_output_dir(self.dir, "-o", inputs, True,
                                   tuple(outputs) + (SETTINGS, JOURNAL) + TEMPORARIES)
        old = self.check(settings, overwrite)
        if not overwrite:
            stale = [p for p in stale if os.path.basename(p).startswith(".")]
        start_output(self.dir, stale)
        if old is None or overwrite:
            from ..io import write_json
            write_json(os.path.join(self.dir, SETTINGS), settings)
            return set()
        return self._finished(output_hw)

    def check(self, settings: dict, overwrite: bool):
        """The settings the directory's frames were made with (None: a new directory);
        without `overwrite`, refuses other settings, or files that are not a batch's."""
        old = self._settings()
        if overwrite:
            return old
        if old is not None and old != settings:
            key = next(k for k in sorted(set(old) | set(settings)) if old.get(k) != settings.get(k))
            raise UsageError(f"-o: {self.dir} holds frames made with {_flag(key)} "
                             f"{old.get(key)!r}, not {settings.get(key)!r}; pass --overwrite "
                             "to make them again, or choose another -o")
        if old is None and os.path.isdir(self.dir) and os.listdir(self.dir):
            raise UsageError(f"-o: {self.dir} is not empty and holds no clss batch output; "
                             "pass --overwrite to replace it, or choose another -o")
        return old

    def record(self, number: int, paths) -> None:
        """Journal frame `number` once all its files (`paths`) are written."""
        files = {os.path.relpath(p, self.dir): os.path.getsize(p) for p in paths}
        with open(os.path.join(self.dir, JOURNAL), "a") as fh:
            fh.write(json.dumps({"frame": number, "files": files}) + "\n")

    def _settings(self):
        path = os.path.join(self.dir, SETTINGS)
        if not os.path.isfile(path):
            return None
        try:
            with open(path) as fh:
                return json.load(fh)
        except ValueError:
            raise UsageError(f"-o: {path} is not a clss batch settings file; pass --overwrite "
                             "to start the sequence again") from None

    def _finished(self, output_hw) -> set:
        path = os.path.join(self.dir, JOURNAL)
        entries = {}
        if os.path.isfile(path):
            with open(path) as fh:
                for line in fh:
                    try:
                        e = json.loads(line)
                        entries[int(e["frame"])] = dict(e["files"])
                    except (ValueError, KeyError, TypeError):
                        continue        # a line the kill cut short
        return {n for n, files in entries.items() if self._intact(files, output_hw)}

    def _intact(self, files: dict, output_hw) -> bool:
        from ..io import InputError, read_header
        for rel, size in files.items():
            p = os.path.join(self.dir, rel)
            try:
                if os.path.getsize(p) != size:
                    return False
                w, h, _ = read_header(p)
            except (OSError, InputError):
                return False
            if os.path.basename(rel).startswith("frame.") and (h, w) != tuple(output_hw):
                return False
        return bool(files)


"""The permission bits a new file gets, for writers that write to a temporary file and
rename it (clss.io's frames, clss.networks' safetensors): they must end with the mode a
plain open() would give, not mkstemp's private 0600."""
from __future__ import annotations

import os


def current_umask() -> int:
    """The process umask (reading it means setting it; set straight back)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def new_file_mode() -> int:
    """What open() would give a new file: 0666 less the umask (mkstemp gives 0600)."""
    return 0o666 & ~current_umask()

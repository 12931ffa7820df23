"""What every reader and writer in :mod:`torchfluidwarp.io` shares: path types, decode-error messages and
atomic outputs (write a temporary sibling, move it into place with ``os.replace`` only on success)."""

from __future__ import annotations

import contextlib
import os
import shutil
import uuid
from collections.abc import Iterator
from pathlib import Path

import torch

from torchfluidwarp._checks import argument_of, describe
from torchfluidwarp.errors import InputError, InputTypeError

PathLike = str | os.PathLike[str]

# Decoders raise all of these for files that are not (complete) images; Pillow uses SyntaxError for
# broken PNG chunks and imageio an OSError when no plugin recognises the data.
DECODE_ERRORS = (OSError, ValueError, RuntimeError, SyntaxError, EOFError)


def first_line(exc: BaseException) -> str:
    """The first line of an exception's message (its type's name when it has none), for one-line errors."""
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


def check_path(name: str, path: object) -> Path:
    """Validate a path argument (a ``str`` or ``os.PathLike``, not empty) and return it as a :class:`Path`."""
    if isinstance(path, bytes) or not isinstance(path, (str, os.PathLike)):
        raise InputTypeError(
            f"{name} must be a str or os.PathLike path, got {describe(path)}", argument=argument_of(name)
        )
    text = os.fspath(path)
    if not isinstance(text, str) or not text:
        raise InputError(f"{name} must be a non-empty path, got {path!r}", argument=argument_of(name))
    return Path(text)


def check_output_path(name: str, path: object, *, folder_ok: bool = False) -> Path:
    """Validate an output path: it must name a file (not ``.`` or ``..``) and, unless ``folder_ok``, must not be
    an existing folder (replacing a folder by a file would delete what it holds)."""
    target = check_path(name, path)
    if target.name in ("", ".", ".."):
        raise InputError(
            f"{name} {str(path)!r} names no file or folder of its own; give it a name", argument=argument_of(name)
        )
    if not folder_ok and target.is_dir():
        raise InputError(
            f"{name} {str(path)!r} is a folder; give a file name (refusing to replace a folder)",
            argument=argument_of(name),
        )
    return target


def make_parents(name: str, target: Path) -> None:
    """Create ``target``'s missing parent folders (after the data was validated, so a refusal leaves none)."""
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
    except (FileExistsError, NotADirectoryError):
        raise InputError(
            f"{name} {str(target)!r}: a parent of it is a file, not a folder", argument=argument_of(name)
        ) from None


def check_float_dtype(name: str, dtype: object) -> torch.dtype:
    """Validate a floating-point ``torch.dtype`` argument."""
    if not isinstance(dtype, torch.dtype) or not dtype.is_floating_point:
        raise InputTypeError(
            f"{name} must be a floating-point torch.dtype, got {describe(dtype)}", argument=argument_of(name)
        )
    return dtype


def check_overwrite(target: Path, overwrite: bool) -> None:
    """Refuse to replace existing output unless asked; never replace a folder of other files."""
    if not (target.exists() or target.is_symlink()):
        return
    if target.is_dir() and not target.is_symlink():
        contents = list(target.iterdir())
        if not contents:
            return
        foreign = [p.name for p in contents if not (p.name.startswith("frame_") and p.suffix == ".png")]
        if foreign:
            raise FileExistsError(
                f"output folder {str(target)!r} holds files other than frames (e.g. {foreign[0]!r}); "
                "refusing to replace it"
            )
    if not overwrite:
        raise FileExistsError(f"output {str(target)!r} already exists; pass overwrite=True to replace it")


@contextlib.contextmanager
def atomic_output(target: Path, *, folder: bool = False) -> Iterator[Path]:
    """Yield a temporary sibling of ``target`` to write; move it onto ``target`` only on success.

    The temporary name starts with a dot and keeps ``target``'s suffix, so writers that choose the
    format by extension still work. On any error it is removed and the error re-raised.
    """
    tmp = target.with_name(f".{target.name}.{uuid.uuid4().hex[:8]}.tmp{'' if folder else target.suffix}")
    if folder:
        tmp.mkdir()
    try:
        yield tmp
        _replace(tmp, target)
    except BaseException:
        _remove(tmp)
        raise


def _replace(tmp: Path, target: Path) -> None:
    """``os.replace`` that also replaces a folder, or a file by a folder (moving the old one aside first)."""
    if not (tmp.is_dir() or target.is_dir()) or not (target.exists() or target.is_symlink()):
        os.replace(tmp, target)
        return
    old = target.with_name(f".{target.name}.{uuid.uuid4().hex[:8]}.old")
    os.replace(target, old)
    try:
        os.replace(tmp, target)
    except BaseException:
        os.replace(old, target)
        raise
    _remove(old)


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        path.unlink(missing_ok=True)

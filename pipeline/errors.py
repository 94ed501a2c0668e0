"""One error hierarchy for zipon.

Every error is a :class:`ZiponError` and also subclasses the matching built-in, so
callers may catch either. Library code raises; only the CLI turns an error into a
message and a non-zero exit. Messages name the file, the field or topic, the frame,
and what was expected.
"""

from __future__ import annotations

import errno
from pathlib import Path


def shown(key: object) -> str:
    """A key or name as a message shows it: as written when printable, else quoted with its escapes, so a key
    holding a newline or a control character cannot break a one-line message or pass unseen."""
    text = str(key)
    return text if text and text.isprintable() else repr(text)


class ZiponError(Exception):
    """Root of every error zipon raises on purpose."""


class ConfigError(ZiponError, ValueError):
    """A params file or override is invalid; the message names the key."""


class InputDataError(ZiponError, ValueError):
    """Raw input (a log, a dataset folder, a user file) is malformed.

    ``where`` collects the file, topic/field and frame so every message reads the same.
    """

    def __init__(
        self,
        message: str,
        *,
        path: str | Path | None = None,
        topic: str | None = None,
        field: str | None = None,
        frame: int | None = None,
        expected: str | None = None,
    ):
        self.path, self.topic, self.field, self.frame, self.expected = path, topic, field, frame, expected
        parts = []
        if path is not None:
            parts.append(f"file {path}")
        if topic is not None:
            parts.append(f"topic {topic}")
        if field is not None:
            parts.append(f"field {field}")
        if frame is not None:
            parts.append(f"frame {frame}")
        text = f"{'; '.join(parts)}: {message}" if parts else message
        if expected:
            text += f" (expected {expected})"
        super().__init__(text)


class PluginError(ZiponError, RuntimeError):
    """An installed plug-in (reader, encoder, agent) failed while zipon imported or ran it; the message names the
    entry point and the package registering it."""


class MissingInputError(ZiponError, FileNotFoundError):
    """A file, artifact or upstream stage output that is needed does not exist."""


class ArtifactError(ZiponError, ValueError):
    """An artifact on disk does not match its contract (format version, arrays, attrs)."""


class LineageError(ZiponError, ValueError):
    """Artifacts that must come from the same upstream version do not."""


class StageError(ZiponError, RuntimeError):
    """A stage could not produce a meaningful output (e.g. an empty scene)."""


class LockedError(ZiponError, RuntimeError):
    """Another live process holds the lock on the outputs this command would write; the message
    names its pid and host."""


_OS_ADVICE = {
    "ENOSPC": "free some space (or point --data-dir at a bigger disk) and rerun",
    "EDQUOT": "free some space (or point --data-dir elsewhere) and rerun",
    "EROFS": "point --data-dir / --manifests-dir at a writable folder",
    "EACCES": "make the folder writable for this user or point --data-dir elsewhere",
    "EPERM": "make the folder writable for this user or point --data-dir elsewhere",
}

# The same for a file the user asked for outside the data root (--out, --png, -o): the data root is not the fix.
_OS_ADVICE_OUTPUT = {
    "ENOSPC": "free some space or write it to another disk",
    "EDQUOT": "free some space or write it elsewhere",
    "EROFS": "write it to a folder on a writable file system",
    "EACCES": "make the folder writable for this user or write it elsewhere",
    "EPERM": "make the folder writable for this user or write it elsewhere",
    "ENOTDIR": "a part of the path is a file, not a folder: choose another path",
    "EISDIR": "the path is a folder: give a file name",
}


def os_error_message(err: OSError, where: str | Path | None = None, *, output: bool = False) -> str:
    """One line for an operating-system error (disk full, read-only, permissions): the path, what
    happened, what to do. The CLI and the runner show this instead of a traceback.

    ``where``: the path to name when the error carries none (``write()`` on a full disk names no file).
    ``output``: the path is a file the user named outside the data root (advice about the data root would not apply).
    """
    code = errno.errorcode.get(err.errno or 0, "")
    where = " -> ".join(str(p) for p in (err.filename, err.filename2) if p is not None) or where or "(no path given)"
    what = err.strerror or str(err)
    text = f"{where}: {what}" + (f" [{code}]" if code else "")
    advice = _OS_ADVICE_OUTPUT if output else _OS_ADVICE
    return f"{text}; {advice[code]}" if code in advice else text

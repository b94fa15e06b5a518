"""What a run leaves behind, written atomically: every file goes to a temporary name in the output
directory and is renamed into place, so an interrupted run never leaves a half-written file."""

import argparse
import io
import json
import math
import os
import tempfile
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from systems.config import ConfigError  # noqa: E402


def check_writable(out_dir: Path) -> None:
    """Raises ConfigError unless `out_dir` exists as a writable directory or can be created.

    Probes by creating and removing a temporary directory in the nearest existing ancestor, which
    also catches read-only file systems and root-owned locations that os.access misjudges."""
    out_dir = Path(out_dir).absolute()
    if out_dir.exists() and not out_dir.is_dir():
        raise ConfigError(f"output path {out_dir} exists and is not a directory")
    ancestor = out_dir
    while not ancestor.exists():
        ancestor = ancestor.parent
    if not ancestor.is_dir():
        raise ConfigError(f"cannot create output directory {out_dir}: {ancestor} is not a directory")
    try:
        os.rmdir(tempfile.mkdtemp(dir=ancestor, prefix=".landing-sim-probe-"))
    except OSError as e:
        raise ConfigError(f"cannot write to output directory {out_dir}: {e.strerror} ({ancestor})") from None


def output_file(text: str) -> Path:
    """argparse type of a benchmark's figures file (`--json FILE`): its folder must exist and be writable and
    the path must not be a folder, so that a mistyped path is refused before the work, not after it."""
    path = Path(text)
    if path.is_dir():
        raise argparse.ArgumentTypeError(f"{path} is a folder, not a file")
    if not path.absolute().parent.is_dir():
        raise argparse.ArgumentTypeError(f"no folder {path.absolute().parent} to write {path.name} in")
    try:
        check_writable(path.absolute().parent)
    except ConfigError as e:
        raise argparse.ArgumentTypeError(str(e)) from None
    return path


def _umask() -> int:
    """The process's umask, read from /proc (Linux 4.7 on) rather than set and restored: os.umask's round trip
    leaves it 0 for a moment, in which another thread's new file (Meshcat's, a video writer's) gets mode 0666."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("Umask:"):
            return int(line.split()[1], 8)
    raise RuntimeError("/proc/self/status has no Umask line (Linux before 4.7?)")


def _write_bytes(path: Path, data: bytes) -> None:
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".partial")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp creates 0600; give the file the usual mode
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def json_default(value):
    """`json.dumps` default for numpy scalars and arrays."""
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(f"cannot write {type(value).__name__} to JSON")


def _finite_or_null(data):
    """`data` with every NaN or infinite float (numpy's, in arrays too) as None: JSON has no such number."""
    if isinstance(data, np.ndarray):
        data = data.tolist()
    if isinstance(data, float | np.floating):
        return float(data) if math.isfinite(data) else None
    if isinstance(data, dict):
        return {key: _finite_or_null(value) for key, value in data.items()}
    if isinstance(data, list | tuple):
        return [_finite_or_null(value) for value in data]
    return data


def write_json(path: Path, data: dict) -> None:
    """`data` as strict JSON: a NaN or infinite number is written as null (Python's json would write NaN,
    which JSON parsers refuse)."""
    text = json.dumps(_finite_or_null(data), indent=2, default=json_default, allow_nan=False)
    _write_bytes(Path(path), (text + "\n").encode())


def write_npz(path: Path, **arrays) -> None:
    buffer = io.BytesIO()
    np.savez_compressed(buffer, **arrays)
    _write_bytes(Path(path), buffer.getvalue())


def write_text(path: Path, text: str) -> None:
    _write_bytes(Path(path), text.encode())


def save_figure(fig, path: Path) -> None:
    """Saves a matplotlib figure as PNG and closes it."""
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=110, bbox_inches="tight")
    plt.close(fig)
    _write_bytes(Path(path), buffer.getvalue())

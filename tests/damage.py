"""Damaged and odd copies of valid recordings, and the contract every one of them must meet.

Used by ``tests/test_faults_inject.py`` (a bounded hypothesis run in CI) and by
``benchmarks/fuzz_inputs.py`` (a longer campaign that counts outcomes per class). Every file is
written by the caller into its own temporary folder; nothing here touches the repository.

The contract, for every damaged or odd input: exit 0 or 1 with every readable frame, or exit 2
with one ``error:`` line naming the file, the frames before the damage kept in ``--out``; never
exit 3, a traceback, a hang, or a changed input.
"""

from __future__ import annotations

import hashlib
import shutil
import struct
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from recording_factory import write_recording

# container -> (writer format, name of the valid source); folders hold their storage file
SOURCES: dict[str, tuple[str, str, str | None]] = {  # container: (format, name, compression)
    "bag": ("bag", "src.bag", None),
    "ros2-db3": ("ros2-db3", "src_db3", None),
    "ros2-mcap": ("ros2-mcap", "src_mcap", None),
    "mcap": ("mcap", "src.mcap", None),
    "mcap-ros1": ("mcap-ros1", "src_ros1.mcap", None),
    # ros2 bag record --compression-mode message: each payload a zstd frame
    "ros2-db3-zstd": ("ros2-db3", "src_db3_zstd", "message"),
    "ros2-mcap-zstd": ("ros2-mcap", "src_mcap_zstd", "message"),
}
FRAMES = 9  # camera frames in every source: three chunks of three, fast to analyse
CHUNK_BYTES = 64 * 1024  # ~3 frames per chunk/bag chunk, so damage can fall between chunks


def make_source(folder: Path, container: str, n: int = FRAMES,
                chunk_bytes: int = CHUNK_BYTES) -> Path:
    fmt, name, compression = SOURCES[container]
    folder.mkdir(parents=True, exist_ok=True)
    return write_recording(folder / name, fmt, n=n, chunk_bytes=chunk_bytes,
                           compression=compression)


def storage_file(rec: Path) -> Path:
    """The file that holds the messages: the recording itself, or the one inside its folder."""
    if rec.is_file():
        return rec
    (f,) = [p for p in rec.iterdir() if p.suffix in (".db3", ".mcap")]
    return f


def copy_recording(src: Path, dest: Path) -> Path:
    if src.is_dir():
        shutil.copytree(src, dest)
    else:
        dest.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(src, dest)
    return dest


def fingerprint(path: Path) -> dict[str, str]:
    files = [path] if path.is_file() else sorted(p for p in path.rglob("*") if p.is_file())
    return {str(p): hashlib.sha256(p.read_bytes()).hexdigest() for p in files}


# -- byte-level damage: (data, a, b) -> damaged data; a and b are fractions in [0, 1) -----------

def cut(data: bytes, a: float, b: float) -> bytes:
    """A recorder killed mid-write: the file ends at a."""
    return data[:max(1, int(len(data) * a))]


def flip(data: bytes, a: float, b: float) -> bytes:
    """One bit flipped at a (a disk or transfer error)."""
    out = bytearray(data)
    i = int(len(out) * a)
    out[i] ^= 1 << int(b * 8)
    return bytes(out)


def zero_run(data: bytes, a: float, b: float) -> bytes:
    """A run of zeros over up to 4 KiB from a (a lost disk block)."""
    out = bytearray(data)
    i = int(len(out) * a)
    n = 1 + int(b * 4096)
    out[i:i + n] = bytes(len(out[i:i + n]))
    return bytes(out)


def zero_tail(data: bytes, a: float, b: float) -> bytes:
    """Cut at a, then zeros (a recorder that preallocated its file and was killed)."""
    keep = int(len(data) * a)
    return data[:keep] + bytes(1 + int(b * 256 * 1024))


def pad_zeros(data: bytes, a: float, b: float) -> bytes:
    """The whole recording, then zeros."""
    return data + bytes(1 + int(b * 256 * 1024))


def bad_length(data: bytes, a: float, b: float) -> bytes:
    """A 4-byte little-endian length near a made huge (or small) -- a corrupt record length."""
    out = bytearray(data)
    i = min(int(len(out) * a), len(out) - 4)
    value = 0xFFFFFFF0 if b < 0.5 else int(b * 64)
    struct.pack_into("<I", out, i, value)
    return bytes(out)


def garbage_tail(data: bytes, a: float, b: float) -> bytes:
    """Bytes that are not a record after the end."""
    return data + bytes((i * 37 + 11) % 256 for i in range(1 + int(b * 2000)))


DAMAGE: dict[str, Callable[[bytes, float, float], bytes]] = {
    "cut": cut, "flip": flip, "zero_run": zero_run, "zero_tail": zero_tail,
    "pad_zeros": pad_zeros, "bad_length": bad_length, "garbage_tail": garbage_tail,
}


def damaged_copy(src: Path, dest: Path, kind: str, a: float, b: float) -> Path:
    """A copy of the recording ``src`` at ``dest`` with its storage file damaged."""
    rec = copy_recording(src, dest)
    f = storage_file(rec)
    f.write_bytes(DAMAGE[kind](f.read_bytes(), a, b))
    return rec


# -- odd but valid: renamed, in awkward folders -----------------------------------------------

def odd_copies(src: Path, folder: Path, container: str) -> list[Path]:
    """Valid recordings that must be read whatever their name or folder."""
    out: list[Path] = []
    for i, name in enumerate(("RUN.BAG", "run", "run.mcap", "run.db3", "a#b?c%20[d]", "run.bag")):
        d = folder / f"odd{i}"
        d.mkdir(parents=True)
        out.append(copy_recording(src, d / name))
    if src.is_dir():  # a folder of bags / db3 whose name looks like a file
        out.append(copy_recording(src, folder / "odd_folder#%?.bag"))
    return out


@dataclass
class Outcome:
    """What one run did, in the classes the campaign counts."""

    code: int | None  # None: did not finish in time
    rows: int
    err: str
    changed: bool
    path: str = ""  # the input, which an error line must name
    forced: str = ""  # a class decided by the caller (a parallel run differing from serial)

    @property
    def klass(self) -> str:
        if self.forced:
            return self.forced
        if self.changed:
            return "changed input"
        if self.code is None:
            return "hang"
        if "Traceback" in self.err:
            return "traceback"
        if self.code in (0, 1):
            return "exit 0/1 with frames" if self.rows else "exit 0/1 WITHOUT frames"
        if self.code == 2:
            line = one_error_line(self.err)
            if line is None:
                return "exit 2 NOT one line"
            return "exit 2 one line" if self.path in line else "exit 2 NOT naming the file"
        return f"exit {self.code}"


def one_error_line(err: str) -> str | None:
    """The single ``error:`` line of a run's stderr (None unless there is exactly one and
    nothing but its hint follows it)."""
    lines = [ln for ln in err.splitlines() if ln.strip()]
    errors = [ln for ln in lines if ln.startswith("error:")]
    if len(errors) != 1 or len(lines) > 2 or not lines[0].startswith("error:"):
        return None
    return errors[0]


GOOD = ("exit 0/1 with frames", "exit 2 one line")

"""No exit status 1 anywhere: every subcommand that reads an input, against a table of hostile inputs.

Exit status 1 means "internal error" (a bug). For each hostile input (a missing file, a dangling
link, a folder, a FIFO, a socket or a device named like a recording, an empty, truncated or garbage
recording, an image named ``.bag``, a Matroska header of unknown size...) and each subcommand, the
run must end with one of pcdof's typed exit codes, one ``pcdof: error:`` line on stderr, and no file
in its output folder. The table runs in this process (click's runner; fast); a sample of it runs
through the console script in subprocesses, where nothing of the test can catch or reformat an error.

Reads are bounded by the file's size, not by a constant: under an address-space limit a small file
is still read (the readers used to reserve 4 GiB for every file).
"""

from __future__ import annotations

import os
import socket
import subprocess
import sys

import numpy as np
import pytest
from click.testing import CliRunner

from pcdof.cli import main
from pcdof.errors import EXIT_CODES

TYPED = set(EXIT_CODES.values())
MAGIC_BAG = b"#ROSBAG V2.0\n"
MAGIC_MKV = b"\x1a\x45\xdf\xa3"


def _png_bytes() -> bytes:
    import cv2

    return cv2.imencode(".png", np.zeros((4, 4, 3), np.uint8))[1].tobytes()


def make_input(kind: str, folder, bag) -> str:
    """The hostile input *kind* in *folder*; returns its path."""
    path = folder / {"fifo-plain": "rec", "newline-name": "a\nb.bag", "png-as-bag": "img.bag",
                     "text-as-mkv": "notes.mkv"}.get(kind, f"rec.{kind.rsplit('-', 1)[-1]}")
    if kind.startswith("missing"):
        pass
    elif kind.startswith("dangling"):
        os.symlink(folder / "gone", path)
    elif kind.startswith("folder"):
        path.mkdir()
    elif kind.startswith("fifo"):
        os.mkfifo(path)
    elif kind.startswith("socket"):
        with socket.socket(socket.AF_UNIX) as s:
            s.bind(os.fspath(path))
    elif kind.startswith("device"):
        os.symlink("/dev/zero", path)
    elif kind.startswith("empty"):
        path.write_bytes(b"")
    elif kind == "magic-only-bag":
        path.write_bytes(MAGIC_BAG)
    elif kind == "garbage-bag" or kind == "newline-name":
        path.write_bytes(MAGIC_BAG + os.urandom(4096))
    elif kind == "truncated-bag":
        data = bag.read_bytes()
        path.write_bytes(data[: len(data) // 3])
    elif kind == "garbage-mkv":
        path.write_bytes(MAGIC_MKV + b"\x9f" + os.urandom(4096))
    elif kind == "unknown-size-mkv":
        path.write_bytes(MAGIC_MKV + b"\xff\x42\x82\x88matroska" + b"\0" * 64)
    elif kind == "png-as-bag":
        path.write_bytes(_png_bytes())
    elif kind == "text-as-mkv":
        path.write_text("hello\n")
    else:
        raise ValueError(kind)
    return os.fspath(path)


INPUTS = ["missing-bag", "dangling-bag", "folder-mkv", "fifo-bag", "fifo-mkv", "fifo-plain", "socket-bag",
          "device-mkv", "empty-bag", "empty-mkv", "magic-only-bag", "garbage-bag", "truncated-bag", "garbage-mkv",
          "unknown-size-mkv", "png-as-bag", "text-as-mkv", "newline-name"]
COMMANDS = {
    "info": lambda out: [],
    "export": lambda out: ["-o", os.fspath(out)],
    "render": lambda out: ["-o", os.fspath(out / "r.png")],
    "register": lambda out: ["-o", os.fspath(out / "reg.png")],
    "cloud": lambda out: ["-o", os.fspath(out / "c.ply")],
    "view": lambda out: ["--screenshot", os.fspath(out / "s.png")],
    "batch": lambda out: ["-o", os.fspath(out)],
}


def check(code: int, stderr: str, out) -> None:
    lines = stderr.splitlines()
    assert code != 1 and code in TYPED, (code, stderr)
    assert len(lines) == 1 and lines[0].startswith("pcdof: error: "), stderr
    assert "Traceback" not in stderr
    assert not out.exists() or not any(files for _, _, files in os.walk(out)), list(os.walk(out))


@pytest.mark.timeout(900)
@pytest.mark.parametrize("command", list(COMMANDS))
def test_every_command_gives_a_typed_exit_code_for_every_hostile_input(sample_bag, tmp_path, command):
    failures = []
    for kind in INPUTS:
        where = tmp_path / kind
        where.mkdir()
        path = make_input(kind, where, sample_bag)
        out = where / "out"
        result = CliRunner().invoke(main, [command, path, *COMMANDS[command](out)])
        try:
            check(result.exit_code, result.stderr, out)
        except AssertionError as err:
            failures.append(f"{kind}: {err}")
    assert not failures, "\n".join(failures)


SAMPLE = [("info", "fifo-bag"), ("render", "fifo-mkv"), ("batch", "fifo-plain"), ("export", "socket-bag"),
          ("view", "garbage-bag"), ("register", "unknown-size-mkv"), ("cloud", "dangling-bag"),
          ("info", "png-as-bag"), ("export", "truncated-bag")]


@pytest.mark.timeout(900)
def test_the_console_script_on_a_sample_of_the_table(sample_bag, tmp_path, console_script):
    from concurrent.futures import ThreadPoolExecutor

    def one(job):
        command, kind = job
        where = tmp_path / f"{command}-{kind}"
        where.mkdir()
        path = make_input(kind, where, sample_bag)
        out = where / "out"
        proc = subprocess.run(console_script + [command, path, *COMMANDS[command](out)], capture_output=True,
                              text=True, timeout=600)
        return job, proc, out

    with ThreadPoolExecutor(max_workers=3) as pool:
        for (command, kind), proc, out in pool.map(one, SAMPLE):
            try:
                check(proc.returncode, proc.stderr, out)
            except AssertionError as err:
                raise AssertionError(f"{command} {kind}: {err}") from None


# --------------------------------------------------------------------------- reads bounded by the file's size
BOUNDED = r"""
import resource, sys
from pcdof.io import read_calibration, read_color, read_depth
from pcdof.io._files import read_bytes, read_text
with open("/proc/self/status") as f:
    vm = next(int(line.split()[1]) * 1024 for line in f if line.startswith("VmSize:"))
limit = vm + (768 << 20)  # what is mapped now and 768 MiB more: far less than the 4 GiB a read once reserved
resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
color, depth, calib = sys.argv[1:4]
assert read_color(color).shape == (48, 64, 3)
assert read_depth(depth, 0.001).shape == (48, 64)
assert read_calibration(calib).color.width == 64
assert read_bytes(calib, "calibration") == open(calib, "rb").read()
status = read_text("/proc/self/status", "status")  # a file whose size is 0 on disk: read whole all the same
assert "VmSize" in status and status.endswith("\n")
print("ok")
"""


def test_reads_fit_under_an_address_space_limit(small_frame):
    proc = subprocess.run([sys.executable, "-c", BOUNDED, *(os.fspath(small_frame[k]) for k in ("color", "depth",
                                                                                              "calib"))],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0 and proc.stdout == "ok\n", proc.stderr


def test_a_file_that_grows_while_read_is_read_whole(tmp_path):
    from pcdof.io._files import open_regular, read_open

    path = tmp_path / "growing.bin"
    path.write_bytes(b"a" * 1000)
    fd, size = open_regular(os.fspath(path), "test")
    with open(path, "ab") as f:  # grows after its size was taken
        f.write(b"b" * (3 << 20))
    data = read_open(fd, size, os.fspath(path), "test")
    assert size == 1000 and data == b"a" * 1000 + b"b" * (3 << 20)

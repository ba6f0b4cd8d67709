"""Ctrl-C at any moment: ``pcdof: interrupted``, exit status 130, within seconds, nothing left behind.

The console script (``pcdof_console``) installs pcdof's handler before anything else loads, so the
sweep below sends SIGINT to ``render``, ``batch`` and ``view --serve`` at delays from the first
moments of the process (while modules are imported and arguments parsed) to the middle of the work.
Each run must end within a few seconds with exit status 130 and exactly one ``pcdof: interrupted``
line on stderr, or, for the server interrupted after it is ready, with 0 and only its "serving" line;
no traceback, no temporary file. The delays start once Python itself has started (measured here: a
signal before that is the interpreter's own, before any code of pcdof exists in the process).
"""

from __future__ import annotations

import glob
import os
import signal
import socket
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor

import pytest

#: longest time from SIGINT to the end of the process, seconds (a loaded two-core machine included)
STOP_WITHIN_S = 12.0
REPEATS = 2


@pytest.fixture(scope="module")
def python_start_s() -> float:
    """How long Python takes here to start and load the console script's module, three processes at once
    (as the sweeps run them), with a margin for a machine whose load changes between the measurement and the
    sweep: the slowest of six, times 2.5, plus 0.1 s (before that, the signal meets Python itself starting)."""
    def once(_):
        t0 = time.monotonic()
        subprocess.run([sys.executable, "-c", "import pcdof_console"], check=True, timeout=120)
        return time.monotonic() - t0

    with ThreadPoolExecutor(max_workers=3) as pool:
        return 2.5 * max(pool.map(once, range(6))) + 0.1


def interrupt_at(command: list[str], delay_s: float, *, ready_port: int | None = None) -> dict:
    """Run *command*, send SIGINT *delay_s* seconds after it starts (or after *ready_port* listens), wait."""
    proc = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        if ready_port is not None:
            deadline = time.monotonic() + 300
            while proc.poll() is None and time.monotonic() < deadline:
                try:
                    socket.create_connection(("127.0.0.1", ready_port), timeout=1).close()
                    break
                except OSError:
                    time.sleep(0.2)
        time.sleep(delay_s)
        finished_first = proc.poll() is not None
        proc.send_signal(signal.SIGINT)
        sent = time.monotonic()
        out, err = proc.communicate(timeout=STOP_WITHIN_S + 60)
        return {"code": proc.returncode, "stdout": out, "stderr": err, "took_s": time.monotonic() - sent,
                "finished_first": finished_first, "delay_s": delay_s}
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()


def check_interrupted(run: dict, done_line: str) -> None:
    """130 and one "interrupted" line; or 0 when the work had ended (its own decision line printed) first."""
    where = f"SIGINT after {run['delay_s']:.2f} s: exit {run['code']}, stderr {run['stderr']!r}"
    assert "Traceback" not in run["stderr"] and "Aborted" not in run["stderr"], where
    assert run["took_s"] < STOP_WITHIN_S, where
    if run["code"] == 0:  # the signal came as the process was ending, its work done
        assert run["finished_first"] or done_line in run["stdout"] + run["stderr"], where
        return
    assert run["code"] == 130, where
    assert run["stderr"].splitlines() == ["pcdof: interrupted"], where


def sweep(command_for, delays, done_line: str, folder) -> None:
    runs = [(i, d) for d in delays for i in range(REPEATS)]
    with ThreadPoolExecutor(max_workers=3) as pool:
        results = list(pool.map(lambda job: (job, interrupt_at(command_for(*job), job[1])), runs))
    for (i, d), run in results:
        check_interrupted(run, done_line)
    left = glob.glob(os.path.join(folder, "**", ".*.tmp"), recursive=True)
    assert not left, left


@pytest.mark.timeout(900)
def test_ctrl_c_during_render(small_frame, tmp_path, console_script, python_start_s):
    def command(i, d):
        out = tmp_path / f"out_{d:.2f}_{i}"
        return console_script + ["render", str(small_frame["color"]), str(small_frame["depth"]), "--calib",
                                 str(small_frame["calib"]), "-o", str(out / "r.png"), "--save-maps", str(out / "maps"),
                                 "--f-number", "2", "--focus-distance", "1"]

    start = python_start_s
    sweep(command, [start + d for d in (0.0, 0.05, 0.15, 0.4, 1.0, 2.5)], "pcdof render:", tmp_path)
    for out in tmp_path.glob("out_*"):  # each run wrote the image and all its maps, or nothing
        written = sorted(p.name for p in out.rglob("*") if p.is_file())
        assert written == [] or "r.png" in written and "trace.json" in written, written


@pytest.mark.timeout(900)
def test_ctrl_c_during_batch(small_sequence, tmp_path, console_script, python_start_s):
    def command(i, d):
        return console_script + ["batch", str(small_sequence), "-o", str(tmp_path / f"out_{d:.2f}_{i}"),
                                 "--f-number", "2", "--no-progress"]

    # one run first, uninterrupted: the kernels this batch takes are then in numba's cache, so the sweep tests
    # the batch's handling of Ctrl-C, not a signal landing in numba's compiler (whose callbacks swallow it)
    subprocess.run(command(0, -1.0), capture_output=True, text=True, timeout=600, check=True)
    start = python_start_s
    sweep(command, [start + d for d in (0.0, 0.1, 0.5, 1.5, 3.0)], "written,", tmp_path)


@pytest.mark.timeout(900)
def test_ctrl_c_during_view_serve(small_frame, console_script, python_start_s):
    def command(port):
        return console_script + ["view", str(small_frame["color"]), str(small_frame["depth"]), "--calib",
                                 str(small_frame["calib"]), "--serve", "--port", str(port)]

    def free_port():
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            return s.getsockname()[1]

    start = python_start_s
    jobs = [(free_port(), start + d, False) for d in (0.0, 0.1, 0.4, 1.5)]
    jobs += [(free_port(), d, True) for d in (0.0, 1.0)]  # after the server is ready

    def one(job):
        port, delay, after_ready = job
        return job, interrupt_at(command(port), delay, ready_port=port if after_ready else None)

    with ThreadPoolExecutor(max_workers=3) as pool:
        results = list(pool.map(one, jobs))
    for (port, delay, after_ready), run in results:
        serving = f"pcdof: serving the viewer on http://127.0.0.1:{port}/ (Ctrl-C to stop)"
        where = f"SIGINT {delay:.2f} s {'after ready' if after_ready else 'after start'}: {run}"
        assert "Traceback" not in run["stderr"] and run["took_s"] < STOP_WITHIN_S, where
        if serving in run["stderr"]:  # stopped after it was ready: a clean stop
            assert run["code"] == 0 and run["stderr"].splitlines() == [serving], where
        else:
            assert not after_ready, where
            assert run["code"] == 130 and run["stderr"].splitlines() == ["pcdof: interrupted"], where


# --------------------------------------------------------------------------- the mechanisms, one by one
STUCK_WORKER = r"""
import sys, threading
import pcdof_console  # noqa: F401 - what the console script imports first
from pcdof import interrupts
interrupts.install()
code = int(sys.argv[2])
lock = threading.Lock()
lock.acquire()
threading.Thread(target=lock.acquire, name="stuck-worker").start()  # not a daemon: would hold the exit forever
with interrupts.raising():
    try:
        raise KeyboardInterrupt if code == interrupts.EXIT_INTERRUPTED else OSError("disk full")
    except (KeyboardInterrupt, OSError):
        if code == interrupts.EXIT_INTERRUPTED:
            interrupts.say_interrupted()
        interrupts.exit_soon(code, grace_s=float(sys.argv[1]))
        sys.exit(code)
"""


@pytest.mark.parametrize("code,stderr", [(130, "pcdof: interrupted\n"), (7, "")])
def test_a_stuck_worker_thread_cannot_hold_the_exit(code, stderr):
    t0 = time.monotonic()
    proc = subprocess.run([sys.executable, "-c", STUCK_WORKER, "1.0", str(code)], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == code and proc.stderr == stderr, proc.stderr
    assert time.monotonic() - t0 < 60


IN_IMPORT = r"""
import os, signal, sys, tempfile
from pcdof import interrupts
interrupts.install()
folder = tempfile.mkdtemp()
sys.path.insert(0, folder)
with open(os.path.join(folder, "slow_module.py"), "w") as f:
    f.write("import os, signal\nos.kill(os.getpid(), signal.SIGINT)\nimport time\ntime.sleep(30)\n")
pending = os.path.join(folder, ".out.png.x.tmp")
open(pending, "w").close()
interrupts.on_interrupt(lambda: os.remove(pending))
print(folder, flush=True)
with interrupts.raising():
    try:
        import slow_module  # noqa: F401
    except KeyboardInterrupt:
        print("raised inside an import", flush=True)
"""


def test_ctrl_c_during_an_import_ends_the_process_at_once_with_the_cleanups():
    proc = subprocess.run([sys.executable, "-c", IN_IMPORT], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 130 and proc.stderr == "pcdof: interrupted\n", proc.stderr
    folder = proc.stdout.split()[0]
    assert "raised inside an import" not in proc.stdout
    assert set(os.listdir(folder)) <= {"slow_module.py", "__pycache__"}  # the pending file was removed


AT_EXIT = r"""
import atexit, os, signal, sys, time
import pcdof_console

def ctrl_c_as_the_process_ends():
    os.kill(os.getpid(), signal.SIGINT)
    time.sleep(0.2)  # the signal is delivered now, or would be
    print("disposition", "ignored" if signal.getsignal(signal.SIGINT) is signal.SIG_IGN else "other", flush=True)

atexit.register(ctrl_c_as_the_process_ends)
sys.argv = ["pcdof"] + sys.argv[1:]
pcdof_console.main()
"""


@pytest.mark.parametrize("args,code", [(["--version"], 0), (["render", "--no-such-flag"], 2)])
def test_ctrl_c_after_the_command_ended_keeps_its_exit_status(args, code):
    """A Ctrl-C as the process ends (exit handlers, the interpreter's shutdown, which otherwise gives SIGINT
    its default action back and the process would end by the signal) leaves the command's own status."""
    proc = subprocess.run([sys.executable, "-c", AT_EXIT, *args], capture_output=True, text=True, timeout=120)
    assert proc.returncode == code, (proc.returncode, proc.stderr)
    assert "interrupted" not in proc.stderr and "Traceback" not in proc.stderr, proc.stderr
    assert proc.stdout.splitlines()[-1] == "disposition ignored", proc.stdout


def test_batch_ctrl_c_inside_numbas_compiler_comes_again_in_pcdofs_code():
    """numba's compiler swallows an exception raised in its callbacks from LLVM: a batch's Ctrl-C that lands
    there is sent again until it raises in pcdof's own code, and the batch stops (it was lost before)."""
    from pcdof.batch.signals import sigterm_interrupts

    compiler = os.sep.join(["", "site-packages", "numba", "core", "compiler_step.py"])
    namespace: dict = {}
    exec(compile("def compile_step(swallowed):\n"
                 "    import os, signal, time\n"
                 "    try:\n"
                 "        os.kill(os.getpid(), signal.SIGINT)\n"
                 "        time.sleep(0.01)\n"
                 "    except BaseException as error:  # what numba's callbacks do with it\n"
                 "        swallowed.append(error)\n", compiler, "exec"), namespace)
    swallowed: list = []
    with sigterm_interrupts():
        namespace["compile_step"](swallowed)
        with pytest.raises(KeyboardInterrupt):
            time.sleep(5)
    assert swallowed == []


# A decode whose library warnings are captured redirects fd 2 (pcdof.io.capture). The child below makes the
# signal arrive at the worst moment: right after the redirection, before the block's try. Its last line must
# reach the real stderr (it went to the deleted capture file before: exit 143 and no "terminated" line).
SIGNAL_IN_REDIRECTION = r"""
import os, signal, sys, time
import cv2, numpy as np
from pcdof import interrupts
from pcdof.io import capture
from pcdof.io._files import decode_image
from pcdof.batch.signals import Terminated, sigterm_interrupts

which, batch = getattr(signal, sys.argv[1]), sys.argv[2] == "batch"
png = cv2.imencode(".png", np.zeros((4, 4), np.uint8))[1].tobytes()
real_dup2 = os.dup2

def dup2(fd, fd2):
    real_dup2(fd, fd2)
    if fd2 == 2 and fd != saved[0]:  # stderr now goes to the capture file
        os.kill(os.getpid(), which)

saved = [os.dup(2)]
real_dup = os.dup

def dup(fd):
    saved[0] = real_dup(fd)
    return saved[0]

os.dup, os.dup2 = dup, dup2  # this process only
capture.enable()
interrupts.install()
try:
    with interrupts.raising(), (sigterm_interrupts() if batch else interrupts.raising()):
        decode_image(png, "png", "frame.png", "colour")
        time.sleep(5)  # the signal comes again here
except Terminated:
    sys.stderr.write("terminated\n")
    sys.exit(143)
except KeyboardInterrupt:
    interrupts.say_interrupted()
    sys.exit(130)
"""


@pytest.mark.parametrize("which,where,code,line", [
    ("SIGTERM", "batch", 143, "terminated"),  # raised a moment later, once stderr is back
    ("SIGINT", "batch", 130, "pcdof: interrupted"),  # the same
    ("SIGINT", "command", 130, "pcdof: interrupted"),  # ends the process at once, stderr given back first
])
def test_a_signal_while_stderr_is_captured_leaves_stderr_to_the_last_line(which, where, code, line):
    proc = subprocess.run([sys.executable, "-c", SIGNAL_IN_REDIRECTION, which, where], capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == code and proc.stderr.splitlines() == [line], (proc.returncode, proc.stderr)


def test_capturing_defers_the_handlers_raise():
    from pcdof import interrupts
    from pcdof.io import capture

    was = capture.enabled()
    capture.enable()
    try:
        assert not interrupts.must_not_raise(None)
        with capture.captured_stderr():
            assert interrupts.must_not_raise(None)
        assert not interrupts.must_not_raise(None)
    finally:
        capture.enable(was)

"""Threads under load: the estimate of other processes' busy cores, the thread count chosen from it, and a frame
that renders alike on one thread or two (so the choice changes time only)."""

from __future__ import annotations

import os

import numba
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pcdof.runtime import threads as plans_threads
from pcdof.errors import InputError
from pcdof.runtime.threads import LOAD_WINDOW_S, CoreLoad, spare_threads, threads_for_load

HZ = os.sysconf("SC_CLK_TCK")  # ticks per second of /proc/stat (100 on Linux)


def _stat(tmp_path, busy_ticks: dict) -> str:
    """A /proc/stat with cores cpu0.. whose busy ticks are *busy_ticks* {core: (user, system, steal)}."""
    lines = [f"cpu  {sum(u for u, _, _ in busy_ticks.values())} 0 0 0 0 0 0 0 0 0"]
    for c, (user, system, steal) in sorted(busy_ticks.items()):
        lines.append(f"cpu{c} {user} 0 {system} 99999 5 0 0 {steal} 0 0")
    lines += ["intr 1 2 3", "ctxt 12345", "btime 1700000000", "processes 10"]
    path = tmp_path / "stat"
    path.write_text("\n".join(lines) + "\n")
    return str(path)


class _Clock:
    def __init__(self):
        self.wall, self.own = 100.0, 5.0

    def advance(self, wall_s, own_s):
        self.wall += wall_s
        self.own += own_s


def _meter(tmp_path, ticks, cpus=(0, 1)):
    clock = _Clock()
    path = _stat(tmp_path, ticks)
    meter = CoreLoad(path, clock=lambda: clock.wall, own_cpu_s=lambda: clock.own)
    meter.cpus = list(cpus)
    return meter, clock, path


class TestCoreLoad:
    def test_others_are_the_busy_time_less_our_own_over_the_window(self, tmp_path):
        meter, clock, _ = _meter(tmp_path, {0: (1000, 0, 0), 1: (500, 0, 0)})
        assert meter.update() is None  # the window starts
        # over 0.5 s: the cores were busy for 0.9 s (90 ticks), 0.2 s of it ours -> others 0.7 s / 0.5 s = 1.4 cores
        clock.advance(0.5, 0.2)
        _stat(tmp_path, {0: (1000 + HZ // 2, HZ // 10, 0), 1: (500 + HZ // 5, 0, HZ // 10)})
        assert meter.update() == pytest.approx(1.4)

    def test_a_short_window_keeps_the_last_estimate(self, tmp_path):
        meter, clock, _ = _meter(tmp_path, {0: (0, 0, 0), 1: (0, 0, 0)})
        meter.update()
        clock.advance(LOAD_WINDOW_S, 0.0)
        _stat(tmp_path, {0: (int(LOAD_WINDOW_S * HZ), 0, 0), 1: (0, 0, 0)})
        assert meter.update() == pytest.approx(1.0)
        clock.advance(LOAD_WINDOW_S / 10, 0.0)  # too short: both cores busy now, but the estimate stays
        _stat(tmp_path, {0: (HZ // 2, 0, 0), 1: (HZ // 2, 0, 0)})
        assert meter.update() == pytest.approx(1.0)

    def test_only_the_cores_the_process_may_use_count(self, tmp_path):
        meter, clock, _ = _meter(tmp_path, {0: (0, 0, 0), 1: (0, 0, 0), 2: (0, 0, 0)}, cpus=(1,))
        meter.update()
        clock.advance(1.0, 0.0)
        _stat(tmp_path, {0: (HZ, 0, 0), 1: (0, HZ // 4, 0), 2: (HZ, 0, 0)})
        assert meter.update() == pytest.approx(0.25)

    def test_our_own_time_never_makes_it_negative(self, tmp_path):
        meter, clock, _ = _meter(tmp_path, {0: (0, 0, 0), 1: (0, 0, 0)})
        meter.update()
        clock.advance(1.0, 0.5)  # ticks lag the precise process clock
        _stat(tmp_path, {0: (HZ * 2 // 5, 0, 0), 1: (0, 0, 0)})
        assert meter.update() == 0.0

    def test_no_statistics_file_means_no_estimate(self, tmp_path):
        meter = CoreLoad(str(tmp_path / "missing"))
        assert meter.update() is None and meter.update() is None

    def test_the_real_file_reads_on_linux(self):
        meter = CoreLoad()
        first = meter.update()
        assert first is None
        if meter.cpus is not None and plans_threads.proc_stat_busy_s("/proc/stat", meter.cpus) is not None:
            meter._start = (meter._start[0] - 1.0, *meter._start[1:])  # pretend a second has passed
            others = meter.update()
            assert others is not None and others >= 0.0


class TestSpareThreads:
    @pytest.mark.parametrize("requested, cores, others, expected", [
        (2, 2, 0.0, 2), (2, 2, 0.49, 2), (2, 2, 0.5, 1), (2, 2, 1.0, 1), (2, 2, 1.97, 1), (2, 2, 3.5, 1),
        (16, 16, 8.2, 8), (4, 16, 3.0, 4), (4, 16, 12.6, 3), (1, 8, 0.0, 1), (3, 2, 0.0, 2)])
    def test_table(self, requested, cores, others, expected):
        assert spare_threads(requested, cores, others) == expected

    def test_no_estimate_keeps_the_request(self):
        assert spare_threads(7, 2, None) == 7

    @given(st.integers(1, 64), st.integers(1, 64), st.floats(0, 200))
    @settings(max_examples=200, deadline=None)
    def test_between_one_and_the_request_and_falling_with_load(self, requested, cores, others):
        n = spare_threads(requested, cores, others)
        assert 1 <= n <= requested
        assert spare_threads(requested, cores, others + 1.0) <= n

    @pytest.mark.parametrize("args, name", [((0, 2, 0.0), "requested"), ((True, 2, 0.0), "requested"),
                                            ((2, 0, 0.0), "cores"), ((2, 2, -0.1), "others_busy"),
                                            ((2, 2, float("nan")), "others_busy")])
    def test_bad_arguments_are_one_line(self, args, name):
        with pytest.raises(InputError, match=name):
            spare_threads(*args)


class _FixedLoad:
    def __init__(self, others, cpus=(0, 1)):
        self.others, self.cpus = others, list(cpus)

    def update(self):
        return self.others


@pytest.mark.skipif(numba.config.NUMBA_NUM_THREADS < 2, reason="needs numba with 2 threads")
class TestThreadsForLoad:
    def test_a_busy_core_leaves_one_thread_inside_and_the_count_restored(self, monkeypatch):
        import cv2

        monkeypatch.delenv(plans_threads.ADAPT_ENV, raising=False)
        numba.set_num_threads(2)
        cv_before = cv2.getNumThreads()
        with threads_for_load(_FixedLoad(1.0)) as n:
            assert n == 1 and numba.get_num_threads() == 1 and cv2.getNumThreads() == 1
        assert numba.get_num_threads() == 2 and cv2.getNumThreads() == cv_before

    def test_idle_cores_and_the_switch_change_nothing(self, monkeypatch):
        monkeypatch.delenv(plans_threads.ADAPT_ENV, raising=False)
        numba.set_num_threads(2)
        with threads_for_load(_FixedLoad(0.1)) as n:
            assert n == 2 and numba.get_num_threads() == 2
        monkeypatch.setenv(plans_threads.ADAPT_ENV, "0")
        with threads_for_load(_FixedLoad(1.5)) as n:
            assert n == 2 and numba.get_num_threads() == 2

    def test_fixed_threads_turns_the_adaptation_off_inside_only(self, monkeypatch):
        from pcdof.runtime.threads import fixed_threads

        monkeypatch.delenv(plans_threads.ADAPT_ENV, raising=False)
        numba.set_num_threads(1)
        with fixed_threads(2) as n:
            assert n == 2
            with threads_for_load(_FixedLoad(1.5)) as m:
                assert m == 2 and numba.get_num_threads() == 2
        assert numba.get_num_threads() == 1
        numba.set_num_threads(2)
        with threads_for_load(_FixedLoad(1.5)) as m:  # outside: adapted again
            assert m == 1

    def test_the_count_is_restored_after_an_error(self, monkeypatch):
        monkeypatch.delenv(plans_threads.ADAPT_ENV, raising=False)
        numba.set_num_threads(2)
        with pytest.raises(RuntimeError):
            with threads_for_load(_FixedLoad(1.0)):
                raise RuntimeError("stage failed")
        assert numba.get_num_threads() == 2


@pytest.mark.skipif(numba.config.NUMBA_NUM_THREADS < 2, reason="needs numba with 2 threads")
@pytest.mark.parametrize("scene", ["portrait", "highlights"])
def test_a_frame_renders_alike_on_one_thread_or_two(scene):
    """The thread count the load picks changes time only: register, fill and render give the same bits."""
    from pcdof.pipeline import run
    from pcdof.synth import generate_scene

    sf = generate_scene(scene, color_size=(160, 120), depth_size=(128, 106), seed=3)
    out = {}
    for n in (1, 2):
        numba.set_num_threads(n)
        try:
            res = run(sf.frame, sf.default_lens)
        finally:
            numba.set_num_threads(2)
        out[n] = res
    assert np.array_equal(out[1].depth_registered_m, out[2].depth_registered_m)
    assert np.array_equal(out[1].depth_filled_m, out[2].depth_filled_m)
    assert np.array_equal(out[1].image, out[2].image)


@pytest.mark.skipif(numba.config.NUMBA_NUM_THREADS < 2, reason="needs numba with 2 threads")
def test_threads_restored_undoes_a_count_the_block_set():
    """A batch rendered in the caller's process sets the process's threads inside ``threads_restored``: the caller
    gets its own count back (it kept the block's count, one thread, for the rest of the process)."""
    import cv2

    from pcdof.runtime.threads import set_process_threads, threads_restored

    before, cv_before = numba.get_num_threads(), cv2.getNumThreads()
    numba.set_num_threads(2)
    try:
        with threads_restored():
            set_process_threads(1)
            assert numba.get_num_threads() == 1
        assert numba.get_num_threads() == 2 and cv2.getNumThreads() == cv_before
    finally:
        numba.set_num_threads(before)
        cv2.setNumThreads(cv_before)

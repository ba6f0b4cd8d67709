"""Browser viewer (pcdof view --serve): the session's renders, then the page driven in headless Chromium.

The frame is two planes: the left half of the image at 1 m, the right half at 3 m, so a click on either
half must focus at exactly that depth.
"""

import os
import shutil
import signal
import socket
import subprocess
import sys
import time

import cv2
import numpy as np
import pytest

from pcdof.camera import Intrinsics, Rig
from pcdof.errors import InputError, LensError
from pcdof.lens import ThinLens
from pcdof.viewer.web.session import ViewSession

W, H = 160, 120
INTR = Intrinsics(W, H, 150.0, 150.0, (W - 1) / 2, (H - 1) / 2)
NEAR_M, FAR_M = 1.0, 3.0
CHROMIUM = "/usr/bin/chromium" if os.path.exists("/usr/bin/chromium") else shutil.which("chromium")
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync"]
#: Growth of the server's resident memory allowed over 200 slider moves, after 40 moves of warm-up.
RSS_MARGIN_MB = 20


def two_plane_frame(seed=0):
    rng = np.random.default_rng(seed)
    color = cv2.resize(rng.integers(0, 256, (H // 8, W // 8, 3), dtype=np.uint8), (W, H),
                       interpolation=cv2.INTER_NEAREST)
    depth = np.full((H, W), FAR_M, np.float32)
    depth[:, : W // 2] = NEAR_M
    return color, depth


def session(**options):
    color, depth = two_plane_frame()
    return ViewSession(color, depth, depth, INTR, ThinLens(50, 1.4, 2.0), **options)


class TestViewSession:
    def test_draft_is_downscaled_full_is_full_size_and_cached(self):
        s = session(draft_max_side=80)
        draft, full = s.render(draft=True), s.render(draft=False)
        assert draft.shape == (60, 80, 3) and full.shape == (H, W, 3)
        assert draft.dtype == full.dtype == np.uint8
        assert s.render(draft=False) is full and s.counts == {"draft": 1, "full": 1}  # same lens: no new render
        s.set_lens(focus_distance_m=NEAR_M)
        assert s.render(draft=False) is not full and s.counts["full"] == 2

    def test_full_render_is_the_pipeline_render(self):
        from pcdof.pipeline import render_from_depth

        s = session()
        s.set_lens(focus_distance_m=FAR_M, f_number=2.0)
        expected, _ = render_from_depth(s.color, s.filled_m, s.lens, INTR.fx)
        np.testing.assert_array_equal(s.render(draft=False), expected)
        # in focus at 3 m: the right half is sharp, the left half blurred
        diff = np.abs(s.render(draft=False).astype(float) - s.color).mean(axis=2)
        assert diff[:, W // 2 + 8:].mean() < 1.0 < 5.0 < diff[:, : W // 2 - 8].mean()

    def test_depth_at_fraction(self):
        s = session()
        assert s.depth_at_fraction(0.25, 0.5) == pytest.approx(NEAR_M)
        assert s.depth_at_fraction(0.75, 0.5) == pytest.approx(FAR_M)
        assert s.depth_at_fraction(1.0, 1.0) == pytest.approx(FAR_M)  # the image's outer edge
        with pytest.raises(InputError, match="x_frac"):
            s.depth_at_fraction(1.5, 0.5)

    def test_numbers_follow_the_lens(self):
        s = session()
        s.set_lens(focus_distance_m=NEAR_M)
        n = s.numbers
        assert n["focus_m"] == NEAR_M and n["near_m"] < NEAR_M < n["far_m"]
        aperture_px = 0.050 / 1.4 * INTR.fx  # thin lens: c(z) = (f / N) fx |1/d_f - 1/z|
        assert n["max_blur_px"] == pytest.approx(aperture_px * abs(1 / NEAR_M - 1 / FAR_M), rel=1e-5)

    def test_invalid(self):
        s = session()
        with pytest.raises(InputError, match="lens fields"):
            s.set_lens(path="/etc/passwd")
        with pytest.raises(LensError):
            s.set_lens(f_number=-1)
        color, depth = two_plane_frame()
        with pytest.raises(InputError, match="filled_m"):
            ViewSession(color, depth, depth[:, :-1], INTR, ThinLens(50, 1.4, 2.0))
        with pytest.raises(LensError, match="ThinLens"):
            ViewSession(color, depth, depth, INTR, "f/1.4")


# --------------------------------------------------------------------------------------------------
# The page in headless Chromium
# --------------------------------------------------------------------------------------------------

def _need_browser():
    if CHROMIUM is None:
        pytest.skip("chromium is not installed (apt-get install -y chromium, or make chromium)")
    try:
        import playwright.sync_api  # noqa: F401
    except ImportError:
        pytest.skip("playwright is not installed (pip install playwright; its browser download is not needed)")


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def start_server(files, out_dir, port):
    cmd = [sys.executable, "-c", "from pcdof.cli import main; main()", "view", *files, "--focal-length", "50",
           "--f-number", "1.4", "--focus-distance", "2.0", "--stride", "1", "--serve", "--port", str(port),
           "--output-dir", str(out_dir)]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 240
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            pytest.fail(f"the server exited with {proc.returncode}: {proc.stderr.read()}")
        try:
            socket.create_connection(("127.0.0.1", port), timeout=1).close()
            return proc
        except OSError:
            time.sleep(0.3)
    proc.kill()
    pytest.fail("the server did not start listening")


def stop_server(proc):
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def rss_mb(pid: int) -> float:
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    raise RuntimeError("no VmRSS")


def write_frame_files(folder) -> list[str]:
    """The two-plane frame as colour, depth and calibration files in *folder*: the server's arguments."""
    from pcdof import io

    color, depth = two_plane_frame()
    io.write_image(folder / "color.png", color)
    io.write_depth(folder / "depth.png", depth)
    io.write_json(folder / "calib.json", Rig.registered(INTR).to_dict())
    return [str(folder / "color.png"), str(folder / "depth.png"), "--calib", str(folder / "calib.json")]


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    """A server for the two-plane frame and a headless Chromium: (server process, browser, url, output dir)."""
    _need_browser()
    from playwright.sync_api import sync_playwright

    folder = tmp_path_factory.mktemp("web")
    files = write_frame_files(folder)
    port = free_port()
    proc = start_server(files, folder / "out", port)
    try:
        with sync_playwright() as pw:
            browser = pw.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
            yield proc, browser, f"http://127.0.0.1:{port}/", folder / "out"
            browser.close()
    finally:
        stop_server(proc)


def state(page, key):
    return page.evaluate(f"window.trame.state.get({key!r})")


def open_page(browser, url, *, kind="full"):
    page = browser.new_page(viewport={"width": 1200, "height": 700})
    page.goto(url)
    page.wait_for_function("window.trame && window.trame.state && "
                           f"window.trame.state.get('preview_kind') === {kind!r}", timeout=120_000)
    page.wait_for_function("document.querySelector('#scene img') !== null", timeout=60_000)
    return page


def wait_state(page, expression, timeout=60_000):
    page.wait_for_function(f"(s => {expression})(window.trame.state)", timeout=timeout)


def scene_updates(page) -> int:
    return state(page, "stats")["scene"]


def focus_slider_thumb(page):
    return page.locator(".v-slider").first.locator(".v-slider-thumb")


class TestPage:
    def test_focus_slider_moves_preview_number_and_plane(self, served):
        _proc, browser, url, _out = served
        page = open_page(browser, url)
        try:
            before = {"preview": state(page, "preview_src"), "focus": page.inner_text("#focus-value"),
                      "scene_img": page.get_attribute("#scene img", "src"), "updates": scene_updates(page)}
            box = focus_slider_thumb(page).bounding_box()
            x, y = box["x"] + box["width"] / 2, box["y"] + box["height"] / 2
            page.mouse.move(x, y)
            page.mouse.down()
            page.mouse.move(x + 80, y, steps=8)
            wait_state(page, "s.get('preview_kind') === 'draft'")  # while dragging: the reduced preview
            page.mouse.move(x + 160, y, steps=8)
            page.mouse.up()
            # settled: the server has applied the slider's last value and rendered it at full resolution
            wait_state(page, "s.get('numbers').focus_m === s.get('focus_m') && s.get('preview_kind') === 'full'")
            focus_m = state(page, "focus_m")
            assert focus_m > 2.0 + 1e-6
            assert state(page, "preview_src") != before["preview"]
            assert page.inner_text("#focus-value") == f"{focus_m:.3f} m" != before["focus"]
            assert state(page, "plane_z_m") == pytest.approx(focus_m, rel=1e-12)  # the focal plane moved
            assert scene_updates(page) > before["updates"]
            page.wait_for_function(f"document.querySelector('#scene img').src !== {before['scene_img']!r}")
            assert state(page, "preview_size") == f"{W} x {H} px"
        finally:
            page.close()

    @pytest.mark.parametrize("x_frac,depth_m", [(0.25, NEAR_M), (0.75, FAR_M), (0.3, NEAR_M)])
    def test_click_on_preview_focuses_at_that_depth(self, served, x_frac, depth_m):
        _proc, browser, url, _out = served
        page = open_page(browser, url)
        try:
            box = page.locator("#preview").bounding_box()
            page.mouse.click(box["x"] + x_frac * box["width"], box["y"] + 0.5 * box["height"])
            wait_state(page, f"Math.abs(s.get('focus_m') - {depth_m}) < 1e-6")
            wait_state(page, "s.get('preview_kind') === 'full'")
            assert page.inner_text("#focus-value") == f"{depth_m:.3f} m"
            assert state(page, "plane_z_m") == pytest.approx(depth_m)
        finally:
            page.close()

    def test_double_click_on_the_scene_focuses_on_the_picked_point(self, served):
        _proc, browser, url, _out = served
        page = open_page(browser, url)
        try:
            box = page.locator("#scene").bounding_box()
            picked = []
            for fx, fy in ((0.5, 0.5), (0.45, 0.55), (0.55, 0.45), (0.4, 0.5), (0.6, 0.5)):
                picks = state(page, "picks")
                page.mouse.dblclick(box["x"] + fx * box["width"], box["y"] + fy * box["height"])
                wait_state(page, f"s.get('picks') > {picks}")
                point = state(page, "picked_point")
                if point is not None:
                    picked.append(point)
                    wait_state(page, f"Math.abs(s.get('focus_m') - {point[2]}) < 1e-9")
            assert picked, f"no double-click hit the point cloud: {state(page, 'message')!r}"
            for point in picked:  # every cloud point lies on one of the two planes
                assert min(abs(point[2] - NEAR_M), abs(point[2] - FAR_M)) < 1e-5
            assert state(page, "focus_m") == pytest.approx(picked[-1][2], abs=1e-9)
        finally:
            page.close()

    def test_download_is_the_full_resolution_render(self, served):
        _proc, browser, url, out_dir = served
        page = open_page(browser, url)
        try:
            with page.expect_download() as info:
                page.click("#download")
            data = np.frombuffer(open(info.value.path(), "rb").read(), np.uint8)
            image = cv2.imdecode(data, cv2.IMREAD_COLOR)
            assert image.shape == (H, W, 3)
            saved = sorted(out_dir.iterdir())
            assert [p.name for p in saved] == [info.value.suggested_filename]
            np.testing.assert_array_equal(cv2.imread(str(saved[0])), image)
        finally:
            page.close()

    def test_second_tab_shares_the_session_without_extra_work(self, served):
        _proc, browser, url, _out = served
        first, second = open_page(browser, url), open_page(browser, url)
        try:
            wait_state(first, "s.get('stats').clients === 2")
            drafts = state(first, "stats")["draft"]
            focus_slider_thumb(first).focus()
            first.keyboard.press("ArrowRight")
            wait_state(first, f"s.get('stats').draft === {drafts + 1}")
            focus_m = state(first, "focus_m")
            second.wait_for_function(f"document.querySelector('#focus-value').innerText === '{focus_m:.3f} m'")
            first.wait_for_timeout(500)
            assert state(second, "stats")["draft"] == drafts + 1  # one render for both tabs
        finally:
            first.close()
            second.close()

    def test_memory_stays_flat_over_200_slider_moves(self, served):
        proc, browser, url, _out = served
        page = open_page(browser, url)
        try:
            focus_slider_thumb(page).focus()

            def move(count):
                for k in range(count):
                    n = scene_updates(page)
                    page.keyboard.press("ArrowRight" if k % 2 == 0 else "ArrowLeft")
                    wait_state(page, f"s.get('stats').scene > {n}")

            move(40)  # warm-up: caches, first allocations
            before = rss_mb(proc.pid)
            move(200)
            after = rss_mb(proc.pid)
            print(f"server RSS {before:.1f} MB -> {after:.1f} MB over 200 slider moves")
            assert after - before < RSS_MARGIN_MB
        finally:
            page.close()


def test_closing_the_last_tab_cancels_pending_work(served, tmp_path):
    """A lens change schedules the full-resolution render; closing the tab right after cancels it."""

    browser = served[1]  # the module's browser (Playwright's sync API runs one at a time); a server of its own

    files = write_frame_files(tmp_path)
    port = free_port()
    proc = start_server(files, tmp_path / "out", port)
    try:
        url = f"http://127.0.0.1:{port}/"
        page = open_page(browser, url)
        counts = state(page, "stats")
        focus_slider_thumb(page).focus()
        page.keyboard.press("ArrowRight")
        wait_state(page, f"s.get('stats').draft === {counts['draft'] + 1}")
        page.close()  # before the full render's delay has passed
        time.sleep(2.0)
        page = open_page(browser, url, kind="draft")  # a new tab reads the shared state: still the draft
        after = state(page, "stats")
        assert after["full"] == counts["full"], "the closed tab's full-resolution render still ran"
        assert after["draft"] == counts["draft"] + 1
        assert after["clients"] == 1
        page.close()
    finally:
        stop_server(proc)
    assert proc.returncode is not None


def test_missing_web_extra_is_one_clear_error(monkeypatch):
    """Without the web extra, --serve says what to install instead of failing on an import."""
    from pcdof.errors import PcdofError
    from pcdof.viewer.web.app import WebViewer

    monkeypatch.setitem(sys.modules, "trame_vuetify", None)  # an import of it now fails
    with pytest.raises(PcdofError, match=r"web extra \(trame_vuetify is missing\).*pcdof\[web\]"):
        WebViewer(session())


def test_session_renders_with_the_commands_options():
    """view's --quality/--linear/--highlights reach the browser viewer's renders (one RenderOptions)."""
    from pcdof.options import RenderOptions
    from pcdof.viewer.scene import render_preview

    color, depth = two_plane_frame()
    color = color.copy()
    color[10:14, 10:14] = 255  # a clipped highlight on the far plane
    lens = ThinLens(50, 1.4, 1.0)
    plain = ViewSession(color, depth, depth, INTR, lens)
    bright = ViewSession(color, depth, depth, INTR, lens, options=RenderOptions(lens=lens, highlights=8))
    a, b = plain.render(draft=False), bright.render(draft=False)
    assert b.astype(int).sum() > a.astype(int).sum()  # the highlight's extra light spread into its disc
    exact = render_preview(color, depth, lens, INTR.fx, options=RenderOptions(lens=lens, quality="exact"))
    np.testing.assert_array_equal(exact, render_preview(color, depth, lens, INTR.fx,
                                                        options=RenderOptions(lens=lens, quality="exact")))
    linear = (color.astype(np.float32) / 255) ** 2.2
    shown = render_preview(linear, depth, lens, INTR.fx, options=RenderOptions(lens=lens, linear=True))
    assert shown.dtype == np.uint8 and abs(float(shown.mean()) - float(a.mean())) < 12  # encoded for the screen

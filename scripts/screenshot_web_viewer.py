"""Screenshot of the browser viewer (``pcdof view --serve``) in headless Chromium.

    .venv/bin/python scripts/screenshot_web_viewer.py [--out docs/images/web_viewer.png] [--size 1400x800]

Starts ``pcdof view --serve`` on a free loopback port for the bundled TUM RGB-D frame, opens the page in
Chromium (Debian's ``chromium`` package, driven by Playwright's Python package; no browser download),
waits for the 3-D view and the full-resolution preview, and writes the screenshot.
"""

from __future__ import annotations

import argparse
import os
import signal
import socket
import subprocess
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
FRAME = os.path.join(ROOT, "data", "real", "tum_rgbd_open3d")
CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync"]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def start_server(args: list[str], port: int, *, timeout_s: float = 180.0) -> subprocess.Popen:
    """Start ``pcdof view ... --serve --port PORT`` and wait until it accepts connections."""
    cmd = [sys.executable, "-c", "from pcdof.cli import main; main()", "view", *args, "--serve", "--port", str(port)]
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise RuntimeError(f"the server exited with {proc.returncode}: {proc.stderr.read()}")
        try:
            socket.create_connection(("127.0.0.1", port), timeout=1).close()
            return proc
        except OSError:
            time.sleep(0.5)
    proc.kill()
    raise RuntimeError(f"the server did not listen on port {port} within {timeout_s} s")


def stop_server(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def main() -> None:
    from playwright.sync_api import sync_playwright

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=os.path.join(ROOT, "docs", "images", "web_viewer.png"))
    parser.add_argument("--size", default="1400x800", help="browser window WIDTHxHEIGHT")
    opts = parser.parse_args()
    width, height = (int(v) for v in opts.size.split("x"))
    frame = [os.path.join(FRAME, "color.png"), os.path.join(FRAME, "depth.png"), "--calib",
             os.path.join(FRAME, "calib.json"), "--focal-length", "50", "--f-number", "1.4", "--focus-at", "330,300"]
    port = free_port()
    server = start_server(frame, port)
    try:
        with sync_playwright() as pw:
            browser = pw.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
            page = browser.new_page(viewport={"width": width, "height": height})
            page.goto(f"http://127.0.0.1:{port}/")
            page.wait_for_function("window.trame && window.trame.state && window.trame.state.get('preview_kind') === 'full'",
                                   timeout=120_000)
            page.wait_for_timeout(3000)  # the 3-D view's first image
            page.screenshot(path=opts.out)
            browser.close()
    finally:
        stop_server(server)
    print(f"wrote {opts.out}")


if __name__ == "__main__":
    main()

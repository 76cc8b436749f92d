"""Make the README's pictures with the code itself: the terminal at the end of a run, and a viewer pair page.

    .venv/bin/python scripts/readme_images.py     writes docs/images/*.png (about 4 minutes)

Plays the default slice with the premise oracle (``conflictbench model=oracle``) into a fresh store, keeps what
the command printed (as a log shows it: the progress line every minute), renders that as a terminal would (rich),
builds the viewer for the store and photographs, in Chromium, the page of a pair whose conflict rollout stopped
where its reference went on.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
IMAGES = REPO / "docs" / "images"
WIDTH = 120  # terminal columns (the tables with their intervals fit 120)
CHROMIUM_ARGS = ["--no-sandbox", "--disable-gpu", "--disable-background-networking", "--disable-component-update"]


def run_and_capture(folder: Path) -> str:
    env = dict(os.environ, COLUMNS=str(WIDTH))
    command = [sys.executable, "-m", "conflictbench.cli", "model=oracle"]  # into folder/results, as a user's would
    done = subprocess.run(command, capture_output=True, text=True, env=env, timeout=1800, check=True, cwd=folder)
    shown = "$ conflictbench model=oracle\n" + done.stderr + done.stdout
    # the live line redraws itself: keep what a terminal ends up showing of it (the last state of each line)
    return "\n".join(line.split("\r")[-1] for line in shown.splitlines())


def terminal_svg(text: str, path: Path) -> None:
    from rich.console import Console
    from rich.text import Text

    console = Console(record=True, width=WIDTH, file=open(os.devnull, "w"), force_terminal=True)
    console.print(Text.from_ansi(text))
    console.save_svg(str(path), title="conflictbench model=oracle")


def photograph(url: str, path: Path, *, width: int, height: int, seek_videos: bool = False, element: str = "") -> None:
    from playwright.sync_api import sync_playwright

    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=chromium, args=CHROMIUM_ARGS)
        page = browser.new_page(viewport={"width": width, "height": height})
        page.goto(url)
        if seek_videos:  # a frame from the middle of each rollout, not its first
            page.evaluate(
                """() => Promise.all([...document.querySelectorAll('video')].map((v) => new Promise((done) => {
                    const seek = () => { v.addEventListener('seeked', done, { once: true });
                                         v.currentTime = v.duration * 0.6; };
                    if (v.readyState >= 1) seek(); else v.addEventListener('loadedmetadata', seek, { once: true });
                })))"""
            )
        page.wait_for_timeout(300)
        (page.locator(element).first if element else page).screenshot(path=str(path))
        browser.close()


def main() -> int:
    argparse.ArgumentParser(description=__doc__.splitlines()[0]).parse_args()
    IMAGES.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as scratch:
        store = Path(scratch) / "results"
        text = run_and_capture(Path(scratch))
        svg = Path(scratch) / "terminal.svg"
        terminal_svg(text, svg)
        frame = Path(scratch) / "terminal.html"  # the picture at a fixed width, nothing around it
        frame.write_text(f'<body style="margin:0"><img src="{svg.name}" style="width:1000px;display:block"></body>')
        photograph(frame.as_uri(), IMAGES / "terminal_end_of_run.png", width=1000, height=600, element="img")

        from conflictbench import plugins
        from conflictbench.view import Selection, build_site

        site = Path(scratch) / "view"
        build_site(store, site, plugins(), Selection(outcome={"qualified failure"}), videos=1, progress=False)
        index = (site / "index.html").read_text()  # its first pair is the one with videos
        name = index.split('href="pairs/', 1)[1].split(".html", 1)[0]
        photograph((site / "pairs" / f"{name}.html").as_uri(), IMAGES / "viewer_pair.png", width=1180, height=1280,
                   seek_videos=True)  # fmt: skip
    print(f"wrote {IMAGES / 'terminal_end_of_run.png'} and {IMAGES / 'viewer_pair.png'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

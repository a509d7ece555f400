"""Make ``benchmarks/compare_report.png``: the README's and the site's picture of ``compare``'s page.

Runs the default sweep (``pointillist compare scenes/edges.xml``) into a temporary folder and
photographs its ``report.html`` in headless Chromium at 1280 x 1080 (the top of the page: the two
plots side by side, then the reference and each sampler at 16 spp with their maps), scaled to 1050
pixels wide. The page names its cached reference
relative to its folder, so nothing of this machine shows in the picture::

    .venv/bin/python benchmarks/report_screenshot.py            # about a minute on 2 cores
"""

from __future__ import annotations

import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
OUTPUT = ROOT / "benchmarks" / "compare_report.png"
FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--no-first-run", "--hide-scrollbars",
         "--virtual-time-budget=30000", "--window-size=1280,1080"]


def main() -> int:
    names = ("chromium", "chromium-browser", "google-chrome")
    browser = next((shutil.which(name) for name in names if shutil.which(name)), None)
    if browser is None:
        print("report_screenshot.py: chromium not found (`make test` installs it)", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory() as work:
        out = Path(work) / "edges"
        subprocess.run([sys.executable, "-m", "pointillist", "compare", "scenes/edges.xml",   # as a reader types it
                        "--out", str(out), "--no-progress"], check=True, cwd=ROOT)
        shot = Path(work) / "shot.png"
        subprocess.run([browser, *FLAGS, f"--user-data-dir={Path(work) / 'profile'}", f"--screenshot={shot}",
                        (out / "report.html").as_uri()], check=True, capture_output=True, timeout=300)
        text = (out / "report.html").read_text(encoding="utf-8")
        assert work not in text.split("<body", 1)[1][:20000], "the page shows this machine's folder"
        from PIL import Image

        image = Image.open(shot).convert("RGB")
        image.resize((1050, round(image.height * 1050 / image.width)), Image.LANCZOS).save(OUTPUT, optimize=True)
    print(f"wrote {OUTPUT}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

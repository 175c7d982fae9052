"""Open a validation report in headless Chromium and confirm that its images render.

    python -m gendr_validation.browser out/validation/report.html [--screenshot shot.png]

A copy of the report gets a script that, on the page's load event, counts the <img> elements that
decoded (complete and naturalWidth > 0) and writes the counts into <body> attributes; Chromium's
``--dump-dom`` prints the DOM after loading, and we read the counts back. Debian's ``chromium``
package provides the browser (install.sh installs it).
"""
from __future__ import annotations

import argparse
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

from gendr.errors import BackendUnavailableError, InputValueError

_CHECKER = """<script>window.addEventListener('load', () => {
  const imgs = Array.from(document.images);
  const ok = imgs.filter(i => i.complete && i.naturalWidth > 0).length;
  document.body.setAttribute('data-images', imgs.length);
  document.body.setAttribute('data-decoded', ok);
});</script>"""

# flags for a root, offline, headless machine (the probe of this machine kind used the same)
_FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
          "--disable-background-networking", "--disable-component-update", "--disable-sync"]


def find_chromium() -> str:
    for name in ("chromium", "chromium-browser", "google-chrome"):
        path = shutil.which(name)
        if path:
            return path
    raise BackendUnavailableError("no Chromium found (Debian: apt-get install chromium; install.sh does it)")


def check_report(html: Path, screenshot: Path | None = None, timeout: float = 120.0) -> dict:
    """``{'images': n, 'decoded': k}`` for the report at ``html``; optionally a PNG screenshot."""
    html = Path(html)
    if not html.is_file():
        raise InputValueError(f"no report at {html}")
    browser = find_chromium()
    text = html.read_text(encoding="utf-8")
    if "</body>" not in text:
        raise InputValueError(f"{html} has no </body>: not a gendr report")
    with tempfile.TemporaryDirectory() as tmp:
        probe = Path(tmp) / "report.html"
        probe.write_text(text.replace("</body>", _CHECKER + "</body>", 1), encoding="utf-8")
        base = [browser, *_FLAGS, f"--user-data-dir={tmp}/profile"]
        dom = subprocess.run([*base, "--dump-dom", probe.as_uri()], capture_output=True, text=True,
                             timeout=timeout, check=True).stdout
        if screenshot is not None:
            subprocess.run([*base, f"--screenshot={Path(screenshot).resolve()}", "--window-size=1280,2400",
                            "--hide-scrollbars", html.resolve().as_uri()], capture_output=True, timeout=timeout, check=True)
    m = re.search(r'<body[^>]*data-images="(\d+)"[^>]*data-decoded="(\d+)"', dom)
    if not m:
        raise InputValueError("Chromium did not run the report's image check (no data-images on <body>)")
    return {"images": int(m.group(1)), "decoded": int(m.group(2))}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("report", type=Path)
    ap.add_argument("--screenshot", type=Path)
    a = ap.parse_args(argv)
    res = check_report(a.report, a.screenshot)
    ok = res["images"] > 0 and res["decoded"] == res["images"]
    print(f"{a.report}: {res['decoded']}/{res['images']} images rendered in headless Chromium"
          + (f"; screenshot {a.screenshot}" if a.screenshot else "") + ("" if ok else "  FAILED"))
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())

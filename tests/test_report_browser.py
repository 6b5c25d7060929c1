"""The report in a real browser: headless Chromium loads the page from disk with networking off,
every embedded image decodes (naturalWidth > 0), every section is in the rendered DOM, and a
screenshot of the page is not blank.

Chromium is the Debian package ``chromium``; the set-up installs it with apt-get when missing and
the test is skipped (with the reason) when that is not possible.
"""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from gprace.cli import main
from test_report_data import make_everything

FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
         "--disable-component-update", "--disable-sync", "--no-first-run", "--hide-scrollbars"]

# added to a copy of the page only: the report itself has no scripts
PROBE = """<script>window.addEventListener('load', function () {
  var imgs = document.images, ok = 0;
  for (var i = 0; i < imgs.length; i++) {
    var good = imgs[i].complete && imgs[i].naturalWidth > 0;
    imgs[i].setAttribute('data-probe', good ? 'loaded' : 'broken');
    if (good) ok++;
  }
  document.body.setAttribute('data-images-loaded', ok + '/' + imgs.length);
});</script>"""


def _chromium() -> str:
    exe = shutil.which("chromium") or shutil.which("chromium-browser")
    if exe:
        return exe
    if shutil.which("apt-get") is None:
        pytest.skip("chromium is not installed and apt-get is not available to install it")
    try:
        r = subprocess.run(["apt-get", "install", "-y", "chromium"], capture_output=True, text=True, timeout=600)
    except (OSError, subprocess.TimeoutExpired) as exc:
        pytest.skip(f"chromium is not installed and `apt-get install -y chromium` failed: {exc}")
    exe = shutil.which("chromium")
    if r.returncode != 0 or not exe:
        last = (r.stderr or r.stdout).strip().splitlines()[-1:] or ["no output"]
        pytest.skip(f"chromium is not installed and `apt-get install -y chromium` failed: {last[0]}")
    return exe


@pytest.fixture(scope="module")
def chromium() -> str:
    return _chromium()


def _run(exe: str, profile: Path, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([exe, *FLAGS, f"--user-data-dir={profile}", *args], capture_output=True, text=True,
                          timeout=120)


def test_report_renders_in_chromium(chromium, tmp_path):
    exp = make_everything(tmp_path / "exp")
    page = tmp_path / "report.html"
    assert main(["report", str(exp), "-o", str(page)]) == 0
    html = page.read_text()
    n_img = len(re.findall(r"<img ", html))
    assert n_img >= 12

    probe = tmp_path / "probe.html"
    probe.write_text(html.replace("</body>", PROBE + "</body>"))
    r = _run(chromium, tmp_path / "profile", "--virtual-time-budget=10000", "--dump-dom", probe.as_uri())
    dom = r.stdout
    assert r.returncode == 0 and "<body" in dom, r.stderr[-2000:]
    assert f'data-images-loaded="{n_img}/{n_img}"' in dom
    assert dom.count('data-probe="loaded"') == n_img and 'data-probe="broken"' not in dom
    for sec in ("timetrial", "h2h", "diagnosis", "gp", "artifacts"):
        assert re.search(rf'<section id="{sec}"', dom), f"section {sec} missing from the rendered page"

    shot = tmp_path / "shot.png"
    r = _run(chromium, tmp_path / "profile", "--window-size=1280,2400", f"--screenshot={shot}", page.as_uri())
    assert shot.exists(), r.stderr[-2000:]
    import matplotlib.image as mpimg

    img = mpimg.imread(shot)[..., :3]
    assert img.shape[:2] == (2400, 1280)
    # not blank: the page has dark text and coloured figure content over its whole height
    for band in np.array_split(img, 4, axis=0):
        assert (band.min(axis=2) < 0.5).mean() > 0.005
    coloured = (img.max(axis=2) - img.min(axis=2)) > 0.25
    assert coloured.mean() > 0.01

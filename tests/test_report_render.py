"""The demo report rendered by a real browser (headless Chromium): every figure loads, nothing overflows.

Chromium is not a dependency of gcpcal; these tests run where ``/usr/bin/chromium`` exists (Debian's
``chromium`` package) and are skipped elsewhere. A copy of ``report.html`` beside the original
(same relative figure paths) gets a small script that, once the page has loaded, writes what the
browser saw into a ``<pre>``: each image's ``naturalWidth``/``naturalHeight`` and ``complete``
flag, and the page's scroll width. ``--dump-dom`` prints the document after load.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import tempfile
from pathlib import Path

import numpy as np
import pytest
from matplotlib import image as mpimg

CHROMIUM = Path("/usr/bin/chromium")
WINDOW_WIDTH_PX = 1280

pytestmark = pytest.mark.skipif(not CHROMIUM.exists(),
                                reason="headless rendering needs /usr/bin/chromium (Debian package 'chromium')")

_PROBE = """<script>
window.addEventListener("load", function () {
  var images = Array.prototype.map.call(document.images, function (img) {
    return {src: img.getAttribute("src"), complete: img.complete, width: img.naturalWidth,
            height: img.naturalHeight, shown: img.getBoundingClientRect().width};
  });
  var out = document.createElement("pre");
  out.id = "render-check";
  out.textContent = JSON.stringify({images: images, scrollWidth: document.documentElement.scrollWidth,
                                    innerWidth: window.innerWidth});
  document.body.appendChild(out);
});
</script>"""


def _render(html_path: Path) -> dict:
    """What Chromium saw on ``html_path`` after load (the probe's JSON)."""
    probe = html_path.with_name(f".render-check-{html_path.stem}.html")
    probe.write_text(html_path.read_text(encoding="utf-8").replace("</body>", _PROBE + "</body>"), encoding="utf-8")
    with tempfile.TemporaryDirectory() as profile:
        cmd = [str(CHROMIUM), "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
               "--disable-background-networking", "--disable-component-update", "--disable-sync",
               f"--user-data-dir={profile}", f"--window-size={WINDOW_WIDTH_PX},2000", "--virtual-time-budget=10000",
               "--dump-dom", probe.as_uri()]
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    probe.unlink()
    m = re.search(r'<pre id="render-check">(.*?)</pre>', proc.stdout, flags=re.S)
    assert m is not None, f"no probe output (rc {proc.returncode}): {proc.stderr[-2000:]}"
    return json.loads(m.group(1).replace("&quot;", '"').replace("&amp;", "&").replace("&lt;", "<").replace("&gt;", ">"))


@pytest.fixture(scope="module")
def demo_report(demo_folder):
    """``gcpcal demo``'s report (the session's demo run, :func:`conftest.demo_folder`)."""
    return demo_folder / "report.html"


def test_every_figure_of_the_demo_report_loads_in_chromium(demo_report):
    seen = _render(demo_report)
    referenced = re.findall(r'<img src="([^"]+)"', demo_report.read_text(encoding="utf-8"))
    assert len(referenced) == 10  # vectors, distortion, attitude, histograms, count, 3 band-to-band, truth, parallax
    assert [i["src"] for i in seen["images"]] == referenced
    for img in seen["images"]:
        height, width = mpimg.imread(demo_report.parent / img["src"]).shape[:2]
        assert img["complete"] and (img["width"], img["height"]) == (width, height), img
        assert 0 < img["shown"] <= seen["innerWidth"], img  # drawn, and scaled into the page
    assert seen["scrollWidth"] <= seen["innerWidth"]  # no table or figure runs off the page


def test_a_broken_figure_is_detected(demo_report, tmp_path):
    """The check is not vacuous: a report whose figure is missing shows a zero-width image."""
    broken = demo_report.with_name("broken.html")
    text = demo_report.read_text(encoding="utf-8")
    broken.write_text(text.replace('src="figures/residual_vectors.png"', 'src="figures/missing.png"', 1),
                      encoding="utf-8")
    try:
        seen = _render(broken)
    finally:
        os.remove(broken)
    widths = {i["src"]: i["width"] for i in seen["images"]}
    assert widths["figures/missing.png"] == 0
    assert np.all([w > 0 for s, w in widths.items() if s != "figures/missing.png"])

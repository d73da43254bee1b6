"""The web page of the reproduction (lbmpipe.reproduction.webpage): maths as MathML built offline, contents,
anchors per claim and figure; and the page the real build writes from the committed
``results/paper``, opened in headless Chromium (Debian's ``chromium`` + ``chromium-driver``,
driven by Selenium): the equations are laid out as mathematics, every image loads, every link
resolves. Skipped, with the reason, where Chromium or its driver is missing (.ci/run installs them).
"""

from __future__ import annotations

import importlib.util
import os
import re
import shutil
import time
from pathlib import Path
from urllib.parse import unquote, urlparse

import pytest
import yaml

from lbmpipe.reproduction import literate, webpage

ROOT = Path(__file__).resolve().parents[1]

FIXTURE_MD = r"""# A reproduction

Intro with $u = Q / A$ inline.

## Method

- **Eq. (3)** $f_i^{eq} = \rho w_i \left[1 + \frac{3\,\mathbf{e}_i \cdot \mathbf{u}}{c^2}\right]$ —
  [code](../x.py#L1 "Eq. 3: f")

$$\frac{dq}{dt} = \frac{1}{2}\, q \otimes (0, \boldsymbol{\Omega})$$

## Claims

| claim | verdict |
| --- | --- |
| 1 | reproduced |
| 2 | not reproduced |

### Appendix

| claim | statistic |
| --- | --- |
| 1 | D = 0.3 |

![fig8_cylinder_orientation](figures/fig8_cylinder_orientation.png)

See [the other level](reproduction_smoke.md#claims).
"""


def _ids(page: str) -> list[str]:
    return re.findall(r'\sid="([^"]+)"', page)


def test_latex_maths_becomes_mathml_at_build_time_with_nothing_fetched_when_viewed():
    page = webpage.markdown_to_html(FIXTURE_MD, title="t")
    assert page.count("<math ") == 3
    assert 'display="block"' in page and "<mfrac>" in page
    assert "$" not in page.split("<main>")[1]  # every formula was converted
    assert not re.search(r"<script|<link\b|(src|href)=\"https?:", page)


def test_claim_rows_figures_and_headings_get_unique_anchors_that_the_contents_link():
    page = webpage.markdown_to_html(FIXTURE_MD)
    ids = _ids(page)
    assert len(ids) == len(set(ids))
    assert {"claim-1", "claim-2", "claim-1-2", "fig-fig8-cylinder-orientation", "method", "claims"} <= set(ids)
    toc = page[page.index('<nav class="toc"'):page.index("</nav>")]
    assert re.findall(r'href="#([^"]+)"', toc) == ["method", "claims", "appendix"]
    assert page.index("</h1>") < page.index('<nav class="toc"')  # contents follow the title
    assert 'href="reproduction_smoke.html#claims"' in page  # .md links point at the page


@pytest.mark.parametrize("formula", [r"\left( x", r"\fracc{1}{2}", r"x^"])
def test_a_formula_latex2mathml_cannot_read_stops_the_build_naming_it(formula):
    with pytest.raises(ValueError, match=re.escape(formula)):
        webpage.markdown_to_html(f"bad ${formula}$ formula")


# ------------------------------------------------------------------------------------------------
# the real page in a real browser

CHROMIUM = shutil.which("chromium") or ("/usr/bin/chromium" if Path("/usr/bin/chromium").exists() else None)
CHROMEDRIVER = shutil.which("chromedriver") or (
    "/usr/bin/chromedriver" if Path("/usr/bin/chromedriver").exists() else None)
SELENIUM = importlib.util.find_spec("selenium") is not None

needs_browser = pytest.mark.skipif(
    not (CHROMIUM and CHROMEDRIVER and SELENIUM),
    reason="headless browser test needs Debian's chromium and chromium-driver "
           "(apt-get install -y chromium chromium-driver) and selenium; missing: "
           + ", ".join(n for n, ok in (("chromium", CHROMIUM), ("chromedriver", CHROMEDRIVER),
                                      ("selenium", SELENIUM)) if not ok))


@pytest.fixture(scope="module")
def built_page(tmp_path_factory):
    """The document and page of the committed ``results/paper``, built by the real build into a
    temporary folder (links relative to it)."""
    if not (ROOT / "results" / "paper" / "claims.csv").is_file():
        pytest.skip("results/paper/claims.csv is not in this checkout")
    config = yaml.safe_load((ROOT / "config.yaml").read_text())
    out = tmp_path_factory.mktemp("page") / "reproduction_paper.md"
    md, stale = literate.build_checked_document(ROOT, "paper", config, out_md=out)
    assert stale == []
    return md, md.with_suffix(".html")


@pytest.fixture(scope="module")
def browser(tmp_path_factory):
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    opts = webdriver.ChromeOptions()
    opts.binary_location = CHROMIUM
    for arg in ("--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
                "--disable-component-update", "--disable-sync", "--no-first-run", "--window-size=1280,1600",
                f"--user-data-dir={tmp_path_factory.mktemp('chromium-profile')}"):
        opts.add_argument(arg)
    driver = webdriver.Chrome(service=Service(executable_path=CHROMEDRIVER), options=opts)
    driver.set_page_load_timeout(30)
    yield driver
    driver.quit()


def _wait(driver, script: str, timeout: float = 15.0):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if driver.execute_script(script):
            return True
        time.sleep(0.1)
    return False


@needs_browser
def test_built_page_in_chromium_renders_equations_loads_images_and_resolves_every_link(built_page, browser):
    md, page = built_page
    browser.get(page.as_uri())
    assert _wait(browser, "return document.readyState === 'complete'")

    # Equations: one MathML element per formula of the Markdown, laid out by the browser as maths.
    n_formulas = len(re.findall(r"\$\$.+?\$\$|\$[^$\n]+\$", md.read_text(encoding="utf-8")))
    maths = browser.execute_script(
        "return [...document.querySelectorAll('math')].map(m => {const r = m.getBoundingClientRect();"
        " return [r.width, r.height, getComputedStyle(m).display];})")
    assert n_formulas >= 21 and len(maths) == n_formulas
    assert all(w > 0 and h > 0 and "math" in disp for w, h, disp in maths), maths
    # a fraction is drawn as a fraction: its numerator above its denominator
    num_bottom, den_top = browser.execute_script(
        "const f = document.querySelector('mfrac'); const a = f.children[0].getBoundingClientRect(),"
        " b = f.children[1].getBoundingClientRect(); return [a.bottom, b.top];")
    assert num_bottom <= den_top + 0.5

    # Images: all loaded.
    assert _wait(browser, "return [...document.images].every(i => i.complete)")
    images = browser.execute_script("return [...document.images].map(i => [i.getAttribute('src'), i.naturalWidth])")
    assert len(images) >= 8
    assert [src for src, w in images if not w > 0] == []

    # Links: anchors exist in the page, local files exist; nothing on the network.
    links = browser.execute_script("return [...document.querySelectorAll('a[href]')].map(a => a.href)")
    assert links
    broken = []
    for href in links:
        url = urlparse(href)
        if url.scheme in ("http", "https"):
            broken.append(f"{href}: a network link in an offline page")
        elif url.scheme == "file":
            target = Path(unquote(url.path))
            if target.resolve() == page.resolve():
                if url.fragment and not browser.execute_script(
                        "return document.getElementById(arguments[0]) !== null", unquote(url.fragment)):
                    broken.append(f"#{url.fragment}: no such anchor")
            elif not target.exists():
                broken.append(f"{href}: no such file")
    assert broken == []
    for anchor in ("claim-1", "fig-fig8-cylinder-orientation", "contents"):
        assert browser.execute_script("return document.getElementById(arguments[0]) !== null", anchor), anchor

    # Screenshot of the claims summary (the table holding claim-1) for a reader to look at.
    # (the whole table, also beyond the window: DevTools' capture with a clip in page coordinates)
    import base64

    # (into $LBMPIPE_SCREENSHOT_DIR when set, to keep it; else beside the page in pytest's folder)
    shot = Path(os.environ.get("LBMPIPE_SCREENSHOT_DIR", page.parent)) / "claims_summary.png"
    shot.parent.mkdir(parents=True, exist_ok=True)
    x, y, w, h = browser.execute_script(
        "const r = document.getElementById('claim-1').closest('table').getBoundingClientRect();"
        " return [r.left + window.scrollX, r.top + window.scrollY, r.width, r.height];")
    png = browser.execute_cdp_cmd("Page.captureScreenshot", {
        "format": "png", "captureBeyondViewport": True,
        "clip": {"x": x, "y": y, "width": w, "height": min(h, 8000), "scale": 1}})
    shot.write_bytes(base64.b64decode(png["data"]))
    assert shot.stat().st_size > 0
    print(f"\nclaims summary screenshot: {shot}")

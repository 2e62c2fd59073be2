"""The browser page, driven in a real browser: Debian's headless Chromium
through Selenium and chromedriver, against a real spokemesh-server. Upload through the
page's file input, the list, a click on a drawn point, the seed's cell volume read off
the page and compared with the REST answer, neighbours clicked in turn, the whole mesh,
the cells, a projected 5-d set, the token prompt, and /docs. A screenshot of each view
is written to $SPOKEMESH_TEST_OUTPUT/ui (build/test-output/ui under ctest).

Also, without a browser: the page's headers (Content-Security-Policy, no inline script),
--no-ui, and the binary points route from the Python client."""

from __future__ import annotations

import json
import os
import re
import time
import urllib.parse
from pathlib import Path

import numpy as np
import pytest

from conftest import missing

try:
    from selenium import webdriver
    from selenium.common.exceptions import TimeoutException
    from selenium.webdriver.chrome.service import Service
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import WebDriverWait
except ImportError:
    missing("Selenium", "python3-selenium")

import spokemesh  # noqa: E402
from conftest import REPO, cli, http, http_json, uniform  # noqa: E402

OUT = Path(os.environ.get("SPOKEMESH_TEST_OUTPUT", REPO / "build" / "test-output")) / "ui"
CHROMIUM, CHROMEDRIVER = "/usr/bin/chromium", "/usr/bin/chromedriver"


@pytest.fixture(scope="module")
def browser():
    """One headless Chromium for the module (WebGL by SwiftShader, as on a machine
    without a GPU). The profile is fresh, so nothing persists between runs."""
    if not (Path(CHROMIUM).exists() and Path(CHROMEDRIVER).exists()):
        missing("Debian's chromium and chromium-driver", "chromium chromium-driver")
    options = webdriver.ChromeOptions()
    options.binary_location = CHROMIUM
    for flag in ["--headless=new", "--no-sandbox", "--disable-dev-shm-usage", "--use-angle=swiftshader",
                 "--enable-unsafe-swiftshader", "--window-size=1400,900", "--disable-gpu-sandbox"]:
        options.add_argument(flag)
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    driver = webdriver.Chrome(service=Service(CHROMEDRIVER), options=options)
    driver.set_page_load_timeout(60)
    OUT.mkdir(parents=True, exist_ok=True)
    yield driver
    driver.quit()


def wait_for(driver, condition, what: str, timeout: float = 60):
    try:
        return WebDriverWait(driver, timeout, poll_frequency=0.05).until(lambda d: condition(d))
    except TimeoutException:
        raise AssertionError(f"page: {what} did not happen within {timeout} s; status: "
                             f"{text(driver, 'view-status')!r} / {text(driver, 'sets-status')!r}; console: "
                             f"{console_errors(driver)}") from None


def text(driver, element_id: str) -> str:
    found = driver.find_elements(By.ID, element_id)
    return found[0].text if found else ""


def console_errors(driver) -> list:
    """Script errors (an answer of 4xx the page asked for and showed is not one)."""
    return [e["message"] for e in driver.get_log("browser") if e["level"] == "SEVERE" and e.get("source") != "network"]


def shot(driver, name: str) -> None:
    driver.save_screenshot(str(OUT / f"{name}.png"))


def first_frame(driver) -> None:
    wait_for(driver, lambda d: d.execute_script("return document.body.dataset.firstFrame === 'true'"), "first frame")


def open_page(driver, url: str) -> None:
    driver.get("about:blank")  # a fresh document each time (the hash alone would not reload)
    driver.get(url)


def click_point(driver, k: int) -> None:
    """Clicks where the page draws point k (its own projection, read through the page's
    test hook), as a user would."""
    x, y = driver.execute_script("return window.spokemeshUi.screenPosition(arguments[0])", k)
    canvas = driver.find_element(By.CSS_SELECTOR, "#canvas-holder canvas")
    ActionChains(driver).move_to_element_with_offset(canvas, int(x - canvas.size["width"] / 2),
                                                     int(y - canvas.size["height"] / 2)).click().perform()


def lone_point(driver, n: int) -> int:
    """A point drawn at least 12 px from every other (so a click names it alone)."""
    xy = np.array(driver.execute_script(
        "return Array.from({length: arguments[0]}, (_, k) => window.spokemeshUi.screenPosition(k))", n))
    size = driver.find_element(By.CSS_SELECTOR, "#canvas-holder canvas").size
    inside = (xy[:, 0] > 40) & (xy[:, 0] < size["width"] - 40) & (xy[:, 1] > 40) & (xy[:, 1] < size["height"] - 40)
    gaps = np.sqrt(((xy[:, None, :] - xy[None, :, :]) ** 2).sum(-1))
    np.fill_diagonal(gaps, np.inf)
    gap = np.where(inside, gaps.min(1), 0)
    k = int(np.argmax(gap))
    assert gap[k] >= 12, f"no point stands alone on the screen (best gap {gap[k]:.1f} px)"
    return k


def seed_volume(driver, seed: int, expected: float | None = None) -> float:
    """The cell volume the page lists for `seed`; with `expected`, waits until the page
    shows that value (an answer for an earlier box may still be on the page)."""
    def shown(d):
        if d.execute_script("return window.spokemeshUi.seed") != seed or text(d, "detail-seed") != str(seed):
            return None
        found = d.find_elements(By.ID, "cell-volume")
        return float(found[0].get_attribute("data-value")) if found else None
    if expected is None:
        return wait_for(driver, shown, f"seed {seed}'s cell")
    try:
        WebDriverWait(driver, 60, poll_frequency=0.05).until(lambda d: shown(d) == expected)
    except TimeoutException:
        raise AssertionError(f"seed {seed}: the page shows volume {shown(driver)}, REST says {expected}") from None
    return expected


def rest_cell(server, pid: str, seed: int, box: str) -> dict:
    status, cell = http_json("GET", f"{server.http}/v1/pointsets/{pid}/seeds/{seed}/cell?box={box}")
    assert status == 200, cell
    return cell


# ---- without a browser -------------------------------------------------------------------


def test_page_headers_and_no_inline_script(server):
    status, headers, body = http("GET", f"{server.http}/")
    assert status == 200 and headers["Content-Type"].startswith("text/html")
    csp = headers["Content-Security-Policy"]
    for directive in ["default-src 'none'", "script-src 'self'", "style-src 'self'", "connect-src 'self'",
                      "frame-ancestors 'none'"]:
        assert directive in csp, csp
    assert "unsafe" not in csp
    assert headers["X-Content-Type-Options"] == "nosniff"
    html = body.decode()
    for page in [html, http("GET", f"{server.http}/docs")[2].decode()]:
        scripts = re.findall(r"<script\b[^>]*>(.*?)</script>", page, re.S)
        assert scripts and all(not s.strip() for s in scripts), "inline script"
        assert not re.search(r"<script(?![^>]*\bsrc=)", page), "a script without src"
        assert " style=" not in page and "<style" not in page and " on" + "click=" not in page
    # The page's own files, and three.js from Debian's libjs-three.
    own = 0
    for name in ["index.html", "docs.html", "app.js", "docs.js", "dom.js", "point_files.js", "app.css", "icon.svg"]:
        status, _, asset = http("GET", f"{server.http}/ui/{name}")
        assert status == 200, name
        own += len(asset)
    assert own <= 1 << 20, f"the page's own files are {own} bytes"
    status, _, three = http("GET", f"{server.http}/ui/three.min.js")
    assert status == 200 and b"REVISION" in three
    assert http("GET", f"{server.http}/ui/OrbitControls.js")[0] == 200
    assert http("GET", f"{server.http}/ui/nothing.js")[0] == 404


def test_no_ui_serves_no_page(start_server):
    s = start_server("--no-ui")
    for path in ["/", "/docs", "/ui/app.js", "/ui/three.min.js"]:
        assert http("GET", s.http + path)[0] == 404, path
    assert "the browser page" not in s.log()
    status, ps = http_json("POST", f"{s.http}/v1/pointsets", {"points": uniform(20, 2, 1).tolist()})
    assert status == 201  # the API is unchanged


def test_points_route_and_python_client(server, tmp_path):
    pts = uniform(1000, 3, 11)
    status, ps = http_json("POST", f"{server.http}/v1/pointsets", {"points": pts.tolist()})
    assert status == 201
    pid = ps["id"]
    status, headers, body = http("GET", f"{server.http}/v1/pointsets/{pid}/points")
    assert status == 200 and f"{pid}.npy" in headers["Content-Disposition"]
    path = tmp_path / "p.npy"
    path.write_bytes(body)
    assert np.array_equal(np.load(path), pts)  # numpy's own reader, bit for bit
    with spokemesh.Client(server.grpc, rest=server.http) as client:
        assert np.array_equal(client.download(pid), pts)
        narrow = client.download(pid, dtype="float32")
        assert narrow.dtype == np.float32 and np.array_equal(narrow, pts.astype(np.float32))
        with pytest.raises(spokemesh.Error) as e:
            client.download("0" * 64)
        assert e.value.code.name == "NOT_FOUND"
    with spokemesh.Client(server.grpc) as client:  # gRPC chunks, the same values
        assert np.array_equal(client.download(pid), pts)
    status, err = http_json("GET", f"{server.http}/v1/pointsets/{pid}/points?dtype=float16")
    assert status == 400 and "dtype" in err["error"]["message"]


# ---- in the browser ----------------------------------------------------------------------


@pytest.mark.parametrize("d", [2, 3])
def test_upload_click_a_seed_and_compare_with_rest(server, browser, tmp_path, d):
    pts = uniform(400 if d == 2 else 600, d, 100 + d)
    source = tmp_path / f"cloud{d}d.txt" if d == 2 else tmp_path / f"cloud{d}d.npy"
    if d == 2:
        np.savetxt(source, pts, delimiter=",", header="x,y", comments="")  # a CSV with a header line
    else:
        np.save(source, pts)
    open_page(browser, server.http + "/")
    wait_for(browser, lambda b: "No point sets" in text(b, "sets-status") or "point set" in text(b, "sets-status"),
             "the list")
    browser.find_element(By.ID, "file").send_keys(str(source))
    wait_for(browser, lambda b: "stored:" in text(b, "upload-status"), "the upload")
    first_frame(browser)
    rows = browser.find_elements(By.CSS_SELECTOR, "#set-table tbody tr")
    names = [r.find_elements(By.TAG_NAME, "td")[0].text for r in rows]
    assert f"cloud{d}d" in names
    row = rows[names.index(f"cloud{d}d")]
    cells = [td.text for td in row.find_elements(By.TAG_NAME, "td")]
    assert cells[2] == str(len(pts)) and cells[3] == str(d)
    pid = urllib.parse.parse_qs(urllib.parse.urlparse(browser.current_url).fragment)["set"][0]
    status, info = http_json("GET", f"{server.http}/v1/pointsets/{pid}")
    assert status == 200 and info["count"] == len(pts) and info["display_name"] == f"cloud{d}d"
    # What the page uploaded is the file's points, bit for bit.
    assert np.array_equal(np.load(__import__("io").BytesIO(http("GET", f"{server.http}/v1/pointsets/{pid}/points")[2])),
                          pts)
    shot(browser, f"points-{d}d")

    seed = lone_point(browser, len(pts))
    click_point(browser, seed)
    box = browser.find_element(By.ID, "box").get_attribute("value")
    cell = rest_cell(server, pid, seed, box)
    seed_volume(browser, seed, cell["volume"])
    status, nb = http_json("GET", f"{server.http}/v1/pointsets/{pid}/seeds/{seed}/neighbors")
    shown = [int(b.get_attribute("data-seed")) for b in browser.find_elements(By.CSS_SELECTOR, "#neighbor-list button")]
    assert shown == nb["neighbors"]
    facets = browser.find_elements(By.CSS_SELECTOR, "#facet-table tbody tr")
    assert len(facets) == len(cell["facets"])
    status, star = http_json("GET", f"{server.http}/v1/pointsets/{pid}/seeds/{seed}/star")
    assert text(browser, "star-simplices") == str(len(star["simplices"]))
    shot(browser, f"seed-{d}d")

    # A neighbour, clicked in the list, becomes the seed.
    other = shown[len(shown) // 2]
    browser.find_element(By.CSS_SELECTOR, f"#neighbor-list button[data-seed='{other}']").click()
    seed_volume(browser, other, rest_cell(server, pid, other, box)["volume"])
    # A typed seed, and a clip box set by hand.
    small = ",".join(["0.25"] * d + ["0.75"] * d)
    field = browser.find_element(By.ID, "box")
    field.clear()
    field.send_keys(small + "\n")
    inside = int(np.argmin(np.abs(pts - 0.5).max(1)))
    seed_field = browser.find_element(By.ID, "seed")
    seed_field.clear()
    seed_field.send_keys(str(inside) + "\n")
    seed_volume(browser, inside, rest_cell(server, pid, inside, small)["volume"])
    browser.find_element(By.ID, "zoom-seed").click()
    shot(browser, f"seed-clipped-{d}d")

    # The whole mesh, streamed from the NDJSON route: its edges are drawn.
    browser.find_element(By.ID, "mode-mesh").click()
    wait_for(browser, lambda b: "edges drawn" in text(b, "view-status"), "the whole mesh")
    simplices = http("GET", f"{server.http}/v1/pointsets/{pid}/simplices?shard=0&shards=1")[2].decode().split()
    assert text(browser, "view-status").startswith(f"{len(simplices)} simplices")
    shot(browser, f"mesh-{d}d")
    # The cells need a box holding every point: the page says so, and reset gives one.
    browser.find_element(By.ID, "mode-cells").click()
    wait_for(browser, lambda b: "the clip box must hold every point" in text(b, "view-status"), "the box hint")
    browser.find_element(By.ID, "box-reset").click()
    wait_for(browser, lambda b: "coloured by volume" in text(b, "view-status"), "the cells")
    # Clipped to the box and coloured by volume: their volumes sum to the box's.
    lo_hi = [float(v) for v in browser.find_element(By.ID, "box").get_attribute("value").split(",")]
    m = re.search(r"(\d+) cells, coloured by volume \(sum ([^)]+)\)", text(browser, "view-status"))
    assert int(m.group(1)) == len(pts)
    box_volume = float(np.prod(np.array(lo_hi[d:]) - np.array(lo_hi[:d])))
    assert abs(float(m.group(2)) - box_volume) < 1e-5 * box_volume
    shot(browser, f"cells-{d}d")
    assert not console_errors(browser), console_errors(browser)


@pytest.mark.parametrize("d", [2, 3])
def test_cells_in_a_domain_of_any_shape(server, browser, tmp_path, d):
    # A domain file chosen on the page: its walls drawn, every cell clipped to it (the
    # areas sum to the domain's), one seed's cell equal to REST's, a bad file named.
    import domain_files as df
    if d == 2:
        rings, area, _ = df.three_holes()
        domain = tmp_path / "holes.geojson"
        df.write_geojson(domain, rings, "Polygon")
        pts = np.random.default_rng(81).random((400, 2)) * 10
        fmt = "geojson"
    else:
        v, f = df.torus(32, 12)
        domain = tmp_path / "torus.off"
        df.write_off(domain, v, f)
        area = df.mesh_volume(v, f)
        pts = df.inside_torus(600, 82)
        fmt = "off"
    status, ps = http_json("POST", f"{server.http}/v1/pointsets", {"points": pts.tolist(), "display_name": "shape"})
    pid = ps["id"]
    open_page(browser, f"{server.http}/#set={pid}")
    first_frame(browser)
    browser.find_element(By.ID, "domain-file").send_keys(str(domain))
    wait_for(browser, lambda b: "volume" in text(b, "domain-info"), "the domain's description")
    assert ("polygon of 4 rings" if d == 2 else "solid of") in text(browser, "domain-info")
    assert not browser.find_element(By.ID, "box").is_enabled()
    browser.find_element(By.ID, "mode-cells").click()
    wait_for(browser, lambda b: "in the domain" in text(b, "view-status"), "the cells in the domain")
    m = re.search(r"(\d+) cells in the domain \S+, coloured by volume \(sum ([^)]+)\)", text(browser, "view-status"))
    assert int(m.group(1)) == len(pts)
    assert abs(float(m.group(2)) - area) < 1e-5 * area
    shot(browser, f"domain-cells-{d}d")
    # The drawing alone (docs/images/domain-cells-*d.png are these).
    browser.find_element(By.ID, "canvas-holder").screenshot(str(OUT / f"domain-cells-{d}d-view.png"))
    seed = 7
    body = domain.read_bytes()
    status, cell = http_json("POST", f"{server.http}/v1/pointsets/{pid}/seeds/{seed}/cell?domain={fmt}", body)
    assert status == 200
    browser.find_element(By.ID, "seed").clear()
    browser.find_element(By.ID, "seed").send_keys(f"{seed}\n")
    seed_volume(browser, seed, cell["volume"])
    walls = [f for f in cell["facets"] if "wall" in f]
    rows = browser.find_elements(By.CSS_SELECTOR, "#facet-table tbody tr")
    assert len(rows) == len(cell["facets"]) and sum("wall" in r.text for r in rows) == len(walls)
    shot(browser, f"domain-seed-{d}d")
    assert not console_errors(browser), console_errors(browser)
    # A domain with a fault: named beside the input; the clip box is back in use.
    bad = tmp_path / "open.off"
    bad.write_text("OFF\n4 3 0\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n3 0 2 1\n3 0 1 3\n3 1 2 3\n")
    browser.find_element(By.ID, "domain-file").send_keys(str(bad))
    wait_for(browser, lambda b: "open boundary" in text(b, "domain-info"), "the domain's fault")
    assert browser.find_element(By.ID, "box").is_enabled()
    browser.find_element(By.ID, "domain-clear").click()


def test_projection_of_a_5d_set(server, browser):
    pts = uniform(300, 5, 55)
    status, ps = http_json("POST", f"{server.http}/v1/pointsets", {"points": pts.tolist(), "display_name": "five"})
    pid = ps["id"]
    open_page(browser, f"{server.http}/#set={pid}&seed=17")
    first_frame(browser)
    assert browser.find_element(By.ID, "projection").is_displayed()
    box = ",".join(["0"] * 5 + ["1"] * 5)
    field = browser.find_element(By.ID, "box")
    field.clear()
    field.send_keys(box + "\n")
    seed_volume(browser, 17, rest_cell(server, pid, 17, box)["volume"])
    assert "projected" in text(browser, "overlay")
    # The third axis set to none: a 2-d projection, still pickable.
    browser.find_element(By.CSS_SELECTOR, "#axis-z option[value='-1']").click()
    browser.find_element(By.CSS_SELECTOR, "#axis-y option[value='3']").click()
    seed = lone_point(browser, len(pts))
    click_point(browser, seed)
    seed_volume(browser, seed)
    shot(browser, "projection-5d")
    browser.find_element(By.ID, "mode-cells").click()
    wait_for(browser, lambda b: "Cells are drawn for 2-d and 3-d sets" in text(b, "view-status"), "the plain refusal")


def test_sizes_beyond_what_the_page_draws_are_said(server, browser):
    pts = uniform(50001, 2, 9)
    status, headers, body = http("POST", f"{server.http}/v1/pointsets?dimension=2&display_name=big", pts.tobytes(),
                                 {"Content-Type": "application/octet-stream"})
    pid = json.loads(body)["id"]
    open_page(browser, f"{server.http}/#set={pid}")
    first_frame(browser)
    browser.find_element(By.ID, "mode-mesh").click()
    wait_for(browser, lambda b: "up to 50000 points; this one has 50001" in text(b, "view-status"), "the mesh limit")
    browser.find_element(By.ID, "mode-cells").click()
    wait_for(browser, lambda b: "up to 20000 points" in text(b, "view-status"), "the cells limit")


def test_token_is_asked_once_and_sent_as_a_header(start_server, browser, tmp_path):
    token_file = tmp_path / "token"
    token_file.write_text("page-s3cret\n")
    s = start_server("--auth-token-file", str(token_file))
    auth = {"Authorization": "Bearer page-s3cret"}
    status, _, body = http("POST", f"{s.http}/v1/pointsets?dimension=2&display_name=secret",
                           uniform(50, 2, 3).tobytes(), {"Content-Type": "application/octet-stream", **auth})
    pid = json.loads(body)["id"]
    open_page(browser, s.http + "/")
    wait_for(browser, lambda b: b.find_element(By.ID, "auth").is_displayed(), "the token prompt")
    assert "Authorization" in text(browser, "sets-status") or "API key" in text(browser, "sets-status")
    browser.find_element(By.ID, "token").send_keys("page-s3cret\n")
    wait_for(browser, lambda b: len(b.find_elements(By.CSS_SELECTOR, "#set-table tbody tr")) == 1, "the list")
    browser.find_element(By.CSS_SELECTOR, "#set-table tbody tr").click()
    first_frame(browser)
    browser.find_element(By.ID, "seed").send_keys("5\n")
    box = browser.find_element(By.ID, "box").get_attribute("value")
    status, cell = http_json("GET", f"{s.http}/v1/pointsets/{pid}/seeds/5/cell?box={box}", headers=auth)
    seed_volume(browser, 5, cell["volume"])
    assert "page-s3cret" not in browser.current_url
    # Held in this tab's sessionStorage only: nothing in localStorage or cookies.
    assert browser.execute_script("return sessionStorage.getItem('spokemesh-token')") == "page-s3cret"
    assert browser.execute_script("return localStorage.length") == 0
    assert not browser.get_cookies()
    assert "page-s3cret" not in s.log()
    shot(browser, "token")
    browser.execute_script("sessionStorage.clear()")


def test_docs_page_renders_every_operation(server, browser):
    open_page(browser, server.http + "/docs")
    wait_for(browser, lambda b: "paths, from /openapi.json" in text(b, "docs-status"), "the docs")
    spec = json.loads(http("GET", f"{server.http}/openapi.json")[2])
    operations = sum(1 for item in spec["paths"].values() for m in ("get", "post", "delete", "put", "patch") if m in item)
    assert len(browser.find_elements(By.CSS_SELECTOR, "#operations section.op")) == operations
    assert len(browser.find_elements(By.CSS_SELECTOR, "#schemas section.op")) == len(spec["components"]["schemas"])
    assert "/v1/pointsets/{id}/points" in browser.find_element(By.ID, "operations").text
    shot(browser, "docs")
    assert not console_errors(browser), console_errors(browser)


def test_drop_a_file_on_the_page(server, browser):
    """The drop box: a file dropped on it (a synthetic drop event carrying a File, as
    the browser's own drag and drop delivers it) is parsed, uploaded and opened; a bad
    one is refused naming its line."""
    open_page(browser, server.http + "/")
    wait_for(browser, lambda b: "point set" in text(b, "sets-status"), "the list")
    drop = """
        const [name, body] = arguments;
        const data = new DataTransfer();
        data.items.add(new File([body], name, {type: 'text/plain'}));
        document.getElementById('drop').dispatchEvent(new DragEvent('drop', {dataTransfer: data, bubbles: true}));
    """
    browser.execute_script(drop, "bad.txt", "0 0\n1 0\n0 x\n")
    wait_for(browser, lambda b: "line 3, column 2" in text(b, "upload-status"), "the bad file's refusal")
    pts = uniform(120, 2, 77)
    browser.execute_script(drop, "dropped.txt", "\n".join(f"{x!r} {y!r}" for x, y in pts) + "\n")
    wait_for(browser, lambda b: "stored:" in text(b, "upload-status"), "the upload")
    first_frame(browser)
    pid = urllib.parse.parse_qs(urllib.parse.urlparse(browser.current_url).fragment)["set"][0]
    status, info = http_json("GET", f"{server.http}/v1/pointsets/{pid}")
    assert info["display_name"] == "dropped" and info["count"] == 120
    status, _, body = http("GET", f"{server.http}/v1/pointsets/{pid}/points")
    assert np.array_equal(np.load(__import__("io").BytesIO(body)), pts)  # repr() round-trips exactly


def test_tenants_see_their_own_sets(start_server, browser, tmp_path):
    keys = tmp_path / "keys"
    keys.write_text("key-alice-0123456789 alice\nkey-bob-0123456789ab bob\n")
    s = start_server("--keys", str(keys))
    for key, name in (("key-alice-0123456789", "alices"), ("key-bob-0123456789ab", "bobs")):
        status, _, _ = http("POST", f"{s.http}/v1/pointsets?dimension=2&display_name={name}",
                            uniform(30, 2, len(name)).tobytes(),
                            {"Content-Type": "application/octet-stream", "Authorization": f"Bearer {key}"})
        assert status == 201
    open_page(browser, s.http + "/")
    wait_for(browser, lambda b: b.find_element(By.ID, "auth").is_displayed(), "the token prompt")
    browser.find_element(By.ID, "token").send_keys("key-bob-0123456789ab\n")
    wait_for(browser, lambda b: text(b, "sets-status") == "1 point set", "bob's list")
    names = [r.find_elements(By.TAG_NAME, "td")[0].text
             for r in browser.find_elements(By.CSS_SELECTOR, "#set-table tbody tr")]
    assert names == ["bobs"]
    browser.execute_script("sessionStorage.clear()")


def _npy_bytes(array: np.ndarray) -> bytes:
    buffer = __import__("io").BytesIO()
    np.save(buffer, array, allow_pickle=False)
    return buffer.getvalue()


FOUR = np.array([[0, 0], [1, 0], [0, 1], [1, 1.5]])
# Point files held to one rule (README "Input"): (name, bytes, accepted).
TEXT_BODY = "0 0\n1 0\n0 1\n1 1.5\n"
POINT_FILES = [
    ("blanks.txt", TEXT_BODY, True),
    ("semicolons.csv", "0;0\n1;0\n0;1\n1;1.5\n", True),
    ("header.csv", "x,y\n0,0\n1,0\n0,1\n1,1.5\n", True),
    ("header_after_comment.txt", "# made by hand\n\nx y\n" + TEXT_BODY, True),
    ("tabs_crlf.txt", "0\t0\r\n1\t0\r\n0\t1\r\n1\t1.5\r\n", True),
    ("comments.txt", "0 0 # origin\n1 0\n0 1\n1 1.5 # last\n", True),
    ("signs_and_points.txt", "+0 0.\n1 -0\n.0 1\n1e0 15e-1\n", True),
    ("header_later.txt", "0 0\nx y\n1 0\n0 1\n1 1.5\n", False),
    ("half_header.txt", "x,1\n" + TEXT_BODY, False),
    ("two_signs.txt", "+-1 0\n" + TEXT_BODY, False),
    ("hex.txt", "0x1 0\n" + TEXT_BODY, False),
    ("infinite.txt", "inf 0\n" + TEXT_BODY, False),
    ("nan.txt", TEXT_BODY + "nan 2\n", False),
    ("huge.txt", TEXT_BODY + "1e101 2\n", False),
    ("ragged.txt", TEXT_BODY + "2 2 2\n", False),
    ("only_header.txt", "x y\n", False),
    ("empty.txt", "", False),
    ("float64.npy", _npy_bytes(FOUR), True),
    ("float32.npy", _npy_bytes(FOUR.astype(np.float32)), True),
    ("int64.npy", _npy_bytes(np.array([[0, 0], [3, 0], [0, 3], [3, 5]], dtype=np.int64)), True),
    ("int32.npy", _npy_bytes(np.array([[0, 0], [3, 0], [0, 3], [3, 5]], dtype=np.int32)), True),
    ("int16.npy", _npy_bytes(np.array([[0, 0], [3, 0], [0, 3], [3, 5]], dtype=np.int16)), True),
    ("int64_beyond_2_53.npy", _npy_bytes(np.array([[0, 0], [1, 0], [0, 1], [2**53 + 1, 5]], dtype=np.int64)), False),
    ("big_endian.npy", _npy_bytes(FOUR.astype(">f8")), False),
    ("uint8.npy", _npy_bytes(FOUR.astype(np.uint8)), False),
    ("three_axes.npy", _npy_bytes(FOUR.reshape(4, 2, 1)), False),
    ("fortran.npy", _npy_bytes(np.asfortranarray(np.array([[0, 0, 1], [1, 0, 2], [0, 1, 3], [1, 1.5, 4]]))), False),
    ("not_finite.npy", _npy_bytes(np.array([[0, 0], [1, 0], [0, np.inf], [1, 1.5]])), False),
]


def test_the_page_and_the_cli_read_point_files_by_one_rule(server, browser, tmp_path):
    """Every file above: the page's parser (point_files.js, in the browser) and the CLI
    (the core's read_points) both accept it, with the same points, or both refuse it."""
    open_page(browser, server.http + "/")
    parse = """
        const [name, b64] = arguments;
        const bytes = Uint8Array.from(atob(b64), (c) => c.charCodeAt(0));
        const files = window.spokemeshPointFiles;
        try {
          const p = name.endsWith('.npy') ? files.parseNpy(bytes.buffer) : files.parseText(new TextDecoder().decode(bytes));
          return {n: p.n, d: p.d, values: Array.from(p.values)};
        } catch (e) {
          return {error: String(e.message)};
        }
    """
    import base64
    disagreements = []
    for name, body, accepted in POINT_FILES:
        raw = body.encode() if isinstance(body, str) else body
        path = tmp_path / name
        path.write_bytes(raw)
        page = browser.execute_script(parse, name, base64.b64encode(raw).decode())
        run = cli("mesh", str(path), "-o", str(tmp_path / (name + ".simplices")), check=False)
        cli_ok = run.returncode == 0
        page_ok = "error" not in page
        if cli_ok != accepted or page_ok != accepted:
            disagreements.append(f"{name}: expected {'accepted' if accepted else 'refused'}; CLI "
                                 f"{'accepted' if cli_ok else 'refused: ' + run.stderr.strip()}; page "
                                 f"{'accepted' if page_ok else 'refused: ' + page['error']}")
            continue
        if accepted:
            n = int(re.search(r"spokemesh: (\d+) points", run.stderr).group(1))
            want = np.load(__import__("io").BytesIO(raw)) if name.endswith(".npy") else None
            assert page["n"] == n == 4 and page["d"] == 2, (name, page, run.stderr)
            if want is not None:
                assert np.array_equal(np.array(page["values"]).reshape(4, 2), want.astype(np.float64)), name
            else:
                assert np.array_equal(np.array(page["values"]).reshape(4, 2), FOUR), name
    assert not disagreements, "\n".join(disagreements)


"""The 3D Tiles viewer page (gnss_citygml/data/viewer/viewer.html) in a real browser: the
values a tile carries (ids, status, method, height_source, the property names) reach the info
box as text, never as markup (no links, forms, remote images or CSS from the data).

The page runs in headless Chromium with a stand-in for CesiumJS (the network is not needed):
the stand-in hands the page's click handler a building whose properties hold HTML, and puts the
description the page makes into a box by ``innerHTML``, as Cesium's info box does. Without
Chromium the test is skipped loudly, and with $CI set it fails (.ci/run installs it)."""

import json
import re
import shutil
import subprocess
from importlib.resources import files

import pytest
from conftest import in_ci

#: What a building's properties hold: markup that must stay text.
HOSTILE = {
    "id": '<a href="https://evil.example/login">Sign in again</a>',
    "status": '<img src="https://evil.example/track.png">',
    "method": "<style>body { display: none }</style>",
    "height_source": '<form action="https://evil.example/"><input name="password"></form>',
    '<b onclick="x()">name</b>': "a property whose name is markup",
    "height": 21.5,
}

#: CesiumJS as far as the page uses it; the building clicked is HOSTILE.
STAND_IN = """
<script>
window.__properties = %s;
const TILESET = { root: { boundingVolume: { region: [0, 0, 0, 0, 0, 0] } } };
window.fetch = async () => ({ json: async () => TILESET });
class Feature {
  getPropertyIds() { return Object.keys(window.__properties); }
  getProperty(name) { return window.__properties[name]; }
}
class Entity { constructor(options) { Object.assign(this, options); } }
window.Cesium = {
  Ion: {}, Cesium3DTileFeature: Feature, Entity,
  ImageryLayer: { fromProviderAsync: () => ({}) },
  OpenStreetMapImageryProvider: class {}, Terrain: { fromWorldTerrain: () => ({}) },
  Cesium3DTileset: { fromUrl: async () => ({ boundingSphere: { radius: 1, center: {} } }) },
  Cesium3DTileStyle: class {}, HeadingPitchRange: class {},
  ScreenSpaceEventType: { LEFT_CLICK: 0 },
  Viewer: class {
    constructor() {
      this.scene = { primitives: { add() {} }, pick: () => new Feature() };
      this.screenSpaceEventHandler = { setInputAction: (handler) => { window.__click = handler; } };
    }
    async zoomTo() {}
    set selectedEntity(entity) { window.__entity = entity; }
  },
};
window.addEventListener("load", () => setTimeout(() => {
  const out = document.createElement("pre");
  out.id = "result";
  try {
    window.__click({ position: {} });
    const box = document.createElement("div");
    box.innerHTML = window.__entity.description;  // as Cesium's info box shows it
    const tags = [...box.querySelectorAll("*")].map((e) => e.tagName.toLowerCase());
    const cells = [...box.querySelectorAll("tr")].map(
      (row) => [...row.children].map((cell) => cell.textContent));
    out.textContent = JSON.stringify({ tags, cells, name: window.__entity.name });
  } catch (error) {
    out.textContent = JSON.stringify({ error: String(error) });
  }
  document.body.appendChild(out);
}, 100));
</script>
"""


def _chromium() -> str:
    for name in ("chromium-headless-shell", "chromium", "chromium-browser", "google-chrome"):
        found = shutil.which(name)
        if found:
            return found
    message = "needs Chromium (apt-get install chromium-headless-shell)"
    if in_ci():
        pytest.fail(f"{message}; with $CI set this is a failure", pytrace=False)
    print(f"\n!!! {message}: the viewer's test did not run !!!")
    pytest.skip(message)


def test_the_info_box_shows_the_datas_markup_as_text(tmp_path):
    page = files("gnss_citygml.data").joinpath("viewer/viewer.html").read_text(encoding="utf-8")
    page, n = re.subn(
        r'<script src="https://cesium\.com/[^"]*"></script>',
        lambda _: STAND_IN % json.dumps(HOSTILE),
        page,
    )
    assert n == 1  # the page loads CesiumJS from its CDN, replaced here
    page = re.sub(r'<link href="https://cesium\.com/[^"]*" rel="stylesheet">', "", page)
    (tmp_path / "viewer.html").write_text(page, encoding="utf-8")
    done = subprocess.run(
        [_chromium(), "--headless", "--no-sandbox", "--disable-gpu", "--virtual-time-budget=5000",
         "--dump-dom", (tmp_path / "viewer.html").as_uri()],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    found = re.search(r'<pre id="result">(.*?)</pre>', done.stdout, re.S)
    assert found, done.stdout[-2000:] + done.stderr[-2000:]
    text = found.group(1).replace("&quot;", '"').replace("&lt;", "<").replace("&gt;", ">")
    result = json.loads(text.replace("&amp;", "&"))
    assert "error" not in result, result
    assert set(result["tags"]) <= {"table", "tbody", "tr", "th", "td"}, result["tags"]
    shown = dict(result["cells"])
    assert shown == {name: str(value) for name, value in HOSTILE.items()}
    assert result["name"] == HOSTILE["id"]

"""The sample city's 3D Tiles in CesiumJS, rendered headless to a PNG for the README
(`make screenshots`):

    python tools/tileset_screenshot.py demo-out/heights.gpkg docs/tileset-cesium.png

Converts the heights to a tileset with their ranges (`gnss-citygml convert ... --ranges`),
serves it with the tileset's own viewer.html over HTTP on localhost, with CesiumJS from npm
(`cesium`, installed into the glTF validator's node folder when missing) instead of its CDN
and without the online imagery (`?offline&lower`), and takes the picture with Chromium
headless (software WebGL: SwiftShader). Needs `chromium` (Debian: apt-get install chromium)
and npm.
"""

from __future__ import annotations

import functools
import http.server
import shutil
import subprocess
import sys
import tempfile
import threading
from pathlib import Path

#: CesiumJS, as viewer.html loads it from the CDN.
CESIUM = "1.123.0"
CDN = f"https://cesium.com/downloads/cesiumjs/releases/{CESIUM[:-2]}/Build/Cesium/"
WIDTH, HEIGHT = 1200, 800


def main(heights: str, png: str) -> int:
    from gnss_citygml.validate.gltf import node_folder

    node = node_folder()
    cesium = node / "node_modules" / "cesium" / "Build" / "Cesium"
    if not cesium.is_dir():
        subprocess.run(["npm", "install", "--prefix", str(node), f"cesium@{CESIUM}"], check=True)
    with tempfile.TemporaryDirectory() as work:
        site = Path(work) / "web"
        subprocess.run(
            [sys.executable, "-m", "gnss_citygml", "convert", heights, "-o",
             str(site / "tileset.json"), "--ranges", "--no-validate", "-q"],
            check=True,
        )  # fmt: skip
        shutil.copytree(cesium, site / "Cesium")
        page = site / "viewer.html"
        page.write_text(page.read_text().replace(CDN, "Cesium/"))
        handler = functools.partial(http.server.SimpleHTTPRequestHandler, directory=str(site))
        server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
        threading.Thread(target=server.serve_forever, daemon=True).start()
        url = f"http://127.0.0.1:{server.server_port}/viewer.html?offline&lower"
        subprocess.run(
            ["chromium", "--headless=new", "--no-sandbox", "--use-angle=swiftshader",
             "--enable-unsafe-swiftshader", "--hide-scrollbars", f"--window-size={WIDTH},{HEIGHT}",
             "--virtual-time-budget=60000", f"--screenshot={Path(png).resolve()}", url],
            check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        )  # fmt: skip
        server.shutdown()
    print(png)
    return 0


if __name__ == "__main__":
    sys.exit(main(*sys.argv[1:]))

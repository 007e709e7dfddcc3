"""Render the top of a report page to a PNG for the README (`make screenshots`):

    python tools/report_screenshot.py demo-out/report.html docs/report-page.png

Headless (Qt's offscreen platform) with QtWebKit, which Debian's PyQt5 has beside QGIS (run it
in the QGIS tests' environment, .venv-qgis, or with /usr/bin/python3).
"""

from __future__ import annotations

import os
import sys

os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")

from PyQt5.QtCore import QEventLoop, QSize, QUrl  # noqa: E402
from PyQt5.QtGui import QImage, QPainter  # noqa: E402
from PyQt5.QtWebKitWidgets import QWebPage  # noqa: E402
from PyQt5.QtWidgets import QApplication  # noqa: E402

WIDTH, HEIGHT = 1100, 1500


def main(page: str, png: str) -> int:
    app = QApplication([])
    web = QWebPage()
    web.setViewportSize(QSize(WIDTH, HEIGHT))
    loop = QEventLoop()
    web.mainFrame().loadFinished.connect(loop.quit)
    web.mainFrame().load(QUrl.fromLocalFile(os.path.abspath(page)))
    loop.exec_()
    image = QImage(QSize(WIDTH, HEIGHT), QImage.Format_RGB32)
    image.fill(0xFFFFFF)
    painter = QPainter(image)
    web.mainFrame().render(painter)
    painter.end()
    image.save(png)
    print(png)
    del app
    return 0


if __name__ == "__main__":
    sys.exit(main(*sys.argv[1:3]))

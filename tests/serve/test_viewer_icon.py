"""The viewer page carries its icon inline, so the browser asks the server for no
/favicon.ico (a 404 in the console before). test_viewer.py checks the console in Chromium."""

import urllib.parse
import xml.etree.ElementTree as ET
from html.parser import HTMLParser
from importlib import resources


class Links(HTMLParser):
    def __init__(self):
        super().__init__()
        self.links = []

    def handle_starttag(self, tag, attrs):
        if tag == "link":
            self.links.append(dict(attrs))


def test_the_viewer_page_has_an_inline_icon():
    page = resources.files("mogo.serve").joinpath("viewer/index.html").read_text("utf-8")
    parser = Links()
    parser.feed(page)
    (icon,) = [link for link in parser.links if link.get("rel") == "icon"]
    kind, _, data = icon["href"].partition(",")
    assert kind == "data:image/svg+xml"
    svg = ET.fromstring(urllib.parse.unquote(data))  # a whole SVG document
    assert svg.tag == "{http://www.w3.org/2000/svg}svg" and len(svg) > 0

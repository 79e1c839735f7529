"""The HTML page of ``staggered view``: the package's page files
(``staggered_cli/viewer/page.html``, ``page.css``, ``page.js`` and the
vendored ``vendor/three.min.js``, read with :mod:`importlib.resources`)
with the motion laid in, one file that needs no network and no server.

The page's description is JSON in ``<script type="application/json"
id="staggered-meta">``; each figure's points are float32 (little-endian)
in base64, cut in pieces of :data:`BLOB_PIECE` characters, each in a
``<script type="application/octet-stream" data-figure="i">`` (a browser
reads a few megabytes of text per element at ease; one string of a
one-hour clip's hundreds of megabytes would be near its limits).
"""

from __future__ import annotations

import base64
import json
import os
from importlib import resources

from ..errors import UsageError

#: Characters of base64 per ``<script>`` element (a multiple of 4).
BLOB_PIECE = 1 << 22

_SLOTS = ("<!--staggered:css-->", "<!--staggered:three-->", "<!--staggered:data-->", "<!--staggered:js-->")


#: Output names a page may have.
PAGE_EXTENSIONS = (".html", ".htm")


def check_page_name(output: str) -> None:
    """Refuse an output name that is not an HTML page's (``-``, standard
    output, is taken): ``view.bvh`` would hold a page under a motion's name."""
    from .files import STDIO
    from .formats import kind_in_name

    if output == STDIO or os.path.splitext(output)[1].lower() in PAGE_EXTENSIONS:
        return
    said = kind_in_name(output)
    says = {None: "", "document": "a document", "gltf": "glTF"}.get(said, str(said).upper())
    because = f" (the name says {says})" if says else ""
    raise UsageError(f"this writes an HTML page: name it .html{because}", source=output)


def asset(name: str) -> str:
    """The text of a page file of the package (``page.js``, ``vendor/three.min.js``, ...)."""
    node = resources.files("staggered_cli.viewer")
    for part in name.split("/"):
        node = node.joinpath(part)
    return node.read_text(encoding="utf-8")


def _script_safe(text: str) -> str:
    """``text`` that cannot close its ``<script>`` element early."""
    return text.replace("</", "<\\/")


def page_pieces(meta: dict, blobs: list[bytes]) -> list[bytes]:
    """The page (UTF-8 pieces, to be written one after another) showing
    ``meta`` (see :func:`staggered_cli.viewer.page_data`) and the float32
    points ``blobs`` of its figures."""
    html = asset("page.html")
    for slot in _SLOTS:
        if html.count(slot) != 1:  # (the package's own file: a bug, not the user's input)
            raise RuntimeError(f"page.html must hold {slot} once")
    three = asset("vendor/three.min.js")
    if "</script" in three.lower():
        raise RuntimeError("vendor/three.min.js holds '</script'")
    data = ['<script type="application/json" id="staggered-meta">', _script_safe(json.dumps(meta, allow_nan=False))]
    data.append("</script>\n")
    out: list[bytes] = []
    fill = {
        _SLOTS[0]: "<style>\n" + asset("page.css") + "</style>",
        _SLOTS[1]: "<script>" + three + "</script>",
        _SLOTS[3]: "<script>\n" + asset("page.js") + "</script>",
    }
    rest = html
    for slot in _SLOTS:
        head, rest = rest.split(slot, 1)
        out.append(head.encode("utf-8"))
        if slot == _SLOTS[2]:
            out.append("".join(data).encode("utf-8"))
            for i, blob in enumerate(blobs):
                text = base64.b64encode(blob)
                for lo in range(0, max(len(text), 1), BLOB_PIECE):
                    out.append(f'<script type="application/octet-stream" data-figure="{i}">'.encode())
                    out.append(text[lo : lo + BLOB_PIECE])
                    out.append(b"</script>\n")
        else:
            out.append(fill[slot].encode("utf-8"))
    out.append(rest.encode("utf-8"))
    return out

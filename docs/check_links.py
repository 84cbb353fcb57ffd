"""Check the built documentation site:

- every internal link: each relative ``href`` / ``src`` must name a file of the build, and
  each ``#fragment`` an ``id`` in that file;
- it works offline: no page loads a script, style sheet or image from another host (math
  comes from the bundled MathJax, ``_static/mathjax``);
- no gallery page shows the build machine's state in an example's output box: numba's
  compile notices ("compiling ...", "... compile in the background", the kernels not in
  numba's cache), which depend on the cache, not on the example.

    python docs/check_links.py [docs/_build/html]

External links (``http(s)://``, ``mailto:``) are not followed (the CI machine is offline);
the theme's own templates under ``_static/`` and viewcode's "[docs]" links back from the
highlighted sources under ``_modules/`` (Sphinx writes some of them under the re-exporting
package's name) are not checked.
Exits 1 and lists what is wrong, else prints how many links were checked.
"""

from __future__ import annotations

import re
import sys
from html.parser import HTMLParser
from pathlib import Path
from urllib.parse import unquote, urlsplit

# Notices whose presence depends on the build machine's numba cache, not on the example.
MACHINE_NOTICES = re.compile(
    r"ltv_lstm_mpc: compiling|in the background|not in numba's cache|ltv_lstm_mpc-compile-",
    re.IGNORECASE,
)


class _Page(HTMLParser):
    def __init__(self) -> None:
        super().__init__()
        self.ids: set[str] = set()
        self.links: list[str] = []
        self.remote: list[str] = []  # resources loaded from another host
        self.outputs: list[str] = []  # text of sphinx-gallery's output boxes
        self._output_depth = 0  # > 0 inside an output box (nested tags counted)

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        classes = (dict(attrs).get("class") or "").split()
        if self._output_depth:
            self._output_depth += 1
        elif "sphx-glr-script-out" in classes:
            self._output_depth = 1
            self.outputs.append("")
        for name, value in attrs:
            if value is None:
                continue
            if name in ("id", "name"):
                self.ids.add(value)
            elif (name == "href" and tag in ("a", "link")) or (
                name == "src" and tag in ("img", "script")
            ):
                self.links.append(value)
            if _loads(tag, name, attrs) and urlsplit(value).netloc:
                self.remote.append(value)

    def handle_endtag(self, tag: str) -> None:
        if self._output_depth:
            self._output_depth -= 1

    def handle_data(self, data: str) -> None:
        if self._output_depth:
            self.outputs[-1] += data


def _loads(tag: str, name: str, attrs: list[tuple[str, str | None]]) -> bool:
    """Whether the browser fetches this attribute's URL to show the page (a script, a
    style sheet, an image, a frame), as opposed to a link the reader may follow."""
    if name == "src":
        return tag in ("script", "img", "iframe", "source", "video", "audio")
    if name == "href" and tag == "link":
        rel = (dict(attrs).get("rel") or "").lower()
        return "stylesheet" in rel or "preload" in rel or "icon" in rel
    return False


def check(root: Path) -> tuple[int, list[str]]:
    """(number of internal links checked, problems as 'page: link or text (why)'): broken
    links, resources from another host and machine-dependent gallery output."""
    pages: dict[Path, _Page] = {}
    for path in sorted(root.rglob("*.html")):
        page = _Page()
        page.feed(path.read_text(encoding="utf-8", errors="replace"))
        pages[path.resolve()] = page
    checked, broken = 0, []
    skipped = (root.resolve() / "_static", root.resolve() / "_modules")
    for path, page in pages.items():
        if path.is_relative_to(skipped[0]) or path.is_relative_to(skipped[1]):
            continue
        page_name = path.relative_to(root.resolve())
        for url in page.remote:
            broken.append(f"{page_name}: {url} (loaded from another host: not offline)")
        for output in page.outputs:
            for line in output.splitlines():
                if MACHINE_NOTICES.search(line):
                    broken.append(f"{page_name}: {line.strip()[:120]!r} (build machine's state)")
        for link in page.links:
            parts = urlsplit(link)
            if parts.scheme or parts.netloc or link.startswith("javascript:"):
                continue
            checked += 1
            target = (path.parent / unquote(parts.path)).resolve() if parts.path else path
            if target.is_dir():
                target = target / "index.html"
            where = f"{path.relative_to(root.resolve())}: {link}"
            if not target.exists():
                broken.append(f"{where} (no file {target})")
                continue
            if parts.fragment and target.suffix == ".html":
                ids = pages[target].ids if target in pages else set()
                if unquote(parts.fragment) not in ids:
                    broken.append(f"{where} (no id {parts.fragment!r})")
    return checked, broken


def main() -> int:
    root = Path(sys.argv[1] if len(sys.argv) > 1 else "docs/_build/html")
    if not (root / "index.html").exists():
        print(f"no built site at {root} (build it with the README's docs command)")
        return 1
    checked, broken = check(root)
    for line in broken:
        print(line)
    print(f"{checked} internal links checked, {len(broken)} problems")
    return 1 if broken else 0


if __name__ == "__main__":
    sys.exit(main())

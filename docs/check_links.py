"""Check every internal link of the built documentation site: each relative ``href`` /
``src`` must name a file of the build, and each ``#fragment`` an ``id`` in that file.

    python docs/check_links.py [docs/_build/html]

External links (``http(s)://``, ``mailto:``) are not followed (the CI machine is offline);
the theme's own templates under ``_static/`` and viewcode's "[docs]" links back from the
highlighted sources under ``_modules/`` (Sphinx writes some of them under the re-exporting
package's name) are not checked.
Exits 1 and lists the broken links, else prints how many were checked.
"""

from __future__ import annotations

import sys
from html.parser import HTMLParser
from pathlib import Path
from urllib.parse import unquote, urlsplit


class _Page(HTMLParser):
    def __init__(self) -> None:
        super().__init__()
        self.ids: set[str] = set()
        self.links: list[str] = []

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        for name, value in attrs:
            if value is None:
                continue
            if name in ("id", "name"):
                self.ids.add(value)
            elif (name == "href" and tag in ("a", "link")) or (name == "src" and tag == "img"):
                self.links.append(value)


def check(root: Path) -> tuple[int, list[str]]:
    """(number of internal links checked, broken ones as 'page: link (why)')."""
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
    print(f"{checked} internal links checked, {len(broken)} broken")
    return 1 if broken else 0


if __name__ == "__main__":
    sys.exit(main())

#!/usr/bin/python3
"""Converts a command page (doc/texsyn*.md) to a man page (section 1).

The pages keep to a small part of Markdown, and this converts that part only:
the title `# texsyn-x(1)`, sections `##` and subsections `###`, paragraphs,
bullet and numbered lists (continued by indented lines), fenced code blocks,
tables (each row becomes a tagged paragraph: the first cell as the tag, the
others as `header: cell`), inline code, bold, italics and links (their text;
a page's link becomes page(1), a guide's link keeps its path). HTML comments
and pictures are left out. The NAME section's names, `texsyn-a, texsyn-b -
what`, are the page's names: each but the page's own gets a stub that sources
the page (`man texsyn-watch` opens texsyn-jobs(1)).

Usage: doc/md2man.py --out DIR PAGE.md ...   (DIR/PAGE.1, and DIR/NAME.1 per other name)
"""
import argparse
import posixpath
import re
import sys
import unicodedata
from pathlib import Path

TITLE = re.compile(r"^# (?P<name>[\w-]+)\((?P<section>\d)\)\s*$")
BULLET = re.compile(r"^([*-]|\d+\.) +")
LINK = re.compile(r"!?\[(?P<text>[^\]]*)\]\((?P<target>[^)\s]*)\)")


def escape(s):
    """Plain text for roff: backslashes, and the characters roff would turn
    into typographic ones (a hyphen for '-', curly quotes), kept as typed so
    that options can be searched for and copied."""
    return (s.replace("\\", "\\e").replace("-", "\\-").replace("'", "\\(aq").replace("`", "\\(ga")
            .replace("^", "\\(ha").replace("~", "\\(ti"))


def link_text(text, target):
    """A link as text: a page becomes page(1); a file of the repository keeps
    its path (from the repository's root) when the text does not name it."""
    path = target.split("#", 1)[0]
    if not path or re.match(r"^[a-z]+:", path):
        return text
    name = posixpath.basename(path)
    if re.fullmatch(r"texsyn[\w-]*\.md", name):
        page = name[:-3]
        return f"{page}(1)" if text.strip("`") == page else f"{text} ({page}(1))"
    repo_path = posixpath.normpath(posixpath.join("doc", path))
    return text if name in text else f"{text} ({repo_path})"


def inline(s):
    """Inline Markdown to roff: code spans kept literally, then links,
    bold and italics."""
    out = []
    for k, part in enumerate(re.split(r"(`[^`]*`)", s)):
        if k % 2:
            out.append("\\fB" + escape(part[1:-1]) + "\\fR")
            continue
        part = LINK.sub(lambda m: "" if m.group(0).startswith("!") else link_text(m.group("text"), m.group("target")),
                        part)
        part = escape(part)
        part = re.sub(r"\*\*(\S(?:.*?\S)?)\*\*", r"\\fB\1\\fR", part)
        part = re.sub(r"(?<![\w*])\*(\S(?:[^*]*?\S)?)\*(?![\w*])", r"\\fI\1\\fR", part)
        out.append(part)
    return protect("".join(out))


def protect(line):
    """A line roff would read as a request (a leading '.' or quote) is
    made text."""
    return "\\&" + line if line.startswith((".", "'")) else line


def ascii_fallback(c):
    """What a terminal without the character shows instead (`.fchar` is used
    only where the device lacks the glyph): the letter without its accent,
    a superscript digit as ^9, a subscript as _1."""
    if c.isascii():
        return None
    base = "".join(b for b in unicodedata.normalize("NFKD", c) if not unicodedata.combining(b))
    if not base or not base.isascii() or not base.isprintable():
        return None
    name = unicodedata.name(c, "")
    return ("^" if name.startswith("SUPERSCRIPT") else "_" if name.startswith("SUBSCRIPT") else "") + base


def cells(row):
    return [c.strip() for c in row.strip().strip("|").split("|")]


class Page:
    def __init__(self, md, source):
        self.lines = md.split("\n")
        self.source = source
        self.out = []
        self.names = []

    def fail(self, k, why):
        raise SystemExit(f"{self.source}:{k + 1}: {why}")

    def convert(self):
        lines, k = self.lines, 0
        m = TITLE.match(lines[0]) if lines else None
        if not m or m.group("name") != Path(self.source).stem:
            self.fail(0, f"a page starts with its title: # {Path(self.source).stem}(1)")
        self.out.append(f'.TH "{m.group("name").upper()}" "{m.group("section")}" "" "texsyn" "texsyn manual"')
        # Left-aligned and unhyphenated: option names and paths stay whole.
        self.out += [".ad l", ".nh"]
        self.out += [f".fchar \\[u{ord(c):04X}] {f}" for c in sorted(set("\n".join(lines)))
                     if (f := ascii_fallback(c))]
        section = None
        k = 1
        while k < len(lines):
            line = lines[k]
            stripped = line.strip()
            if not stripped:
                k += 1
            elif stripped.startswith("<!--"):
                while "-->" not in lines[k]:
                    k += 1
                k += 1
            elif line.startswith("## "):
                section = line[3:].strip().upper()
                self.out.append(f'.SH "{escape(section)}"')
                k += 1
            elif line.startswith("### "):
                self.out.append(f'.SS "{inline(line[4:].strip())}"')
                k += 1
            elif line.startswith("#"):
                self.fail(k, "only ## sections and ### subsections follow the title")
            elif stripped.startswith("```"):
                k = self.code(k)
            elif stripped.startswith("|"):
                k = self.table(k)
            elif BULLET.match(stripped):
                k = self.item(k)
            elif re.fullmatch(r"!\[[^\]]*\]\([^)]*\)", stripped):
                k += 1
            else:
                k = self.paragraph(k, section)
        return "\n".join(self.out) + "\n"

    def paragraph(self, k, section):
        text = []
        while k < len(self.lines) and self.lines[k].strip() and not self.starts_block(self.lines[k]):
            text.append(self.lines[k].strip())
            k += 1
        if section == "NAME":
            self.names = [n.strip() for n in " ".join(text).split(" - ", 1)[0].split(",")]
        self.out.append(".PP")
        self.out.extend(inline(t) for t in text)
        return k

    def starts_block(self, line):
        s = line.strip()
        return line.startswith("#") or s.startswith(("```", "|", "<!--")) or bool(BULLET.match(s))

    def item(self, k):
        first = self.lines[k].strip()
        mark = BULLET.match(first).group(1)
        self.out.append(f'.IP "{mark if mark[0].isdigit() else chr(92) + "(bu"}" 4')
        self.out.append(inline(first[BULLET.match(first).end():]))
        k += 1
        while k < len(self.lines) and self.lines[k].startswith("  ") and self.lines[k].strip():
            s = self.lines[k].strip()
            if s.startswith("```"):
                break
            self.out.append(inline(s))
            k += 1
        return k

    def code(self, k):
        indent = len(self.lines[k]) - len(self.lines[k].lstrip())
        k += 1
        self.out += [".PP" if indent == 0 else ".IP", ".RS 4" if indent == 0 else ".RS 0", ".nf"]
        while k < len(self.lines) and not self.lines[k].strip().startswith("```"):
            self.out.append(protect(escape(self.lines[k][indent:])))
            k += 1
        if k == len(self.lines):
            self.fail(k - 1, "a code block is not closed")
        self.out += [".fi", ".RE"]
        return k + 1

    def table(self, k):
        rows = []
        while k < len(self.lines) and self.lines[k].strip().startswith("|"):
            rows.append(cells(self.lines[k]))
            k += 1
        if len(rows) < 2 or not all(re.fullmatch(r":?-+:?", c) for c in rows[1]):
            self.fail(k - len(rows), "a table has a header row and a |---| row")
        head, body = rows[0], rows[2:]
        for row in body:
            self.out += [".TP", inline(row[0]) or "\\&"]
            rest = [f"{h}: {c}" if h else c for h, c in zip(head[1:], row[1:]) if c]
            self.out.append(inline("; ".join(rest)) if rest else "\\&")
        return k


def convert(path):
    """(man page text, its names) of a page."""
    page = Page(Path(path).read_text(), path)
    text = page.convert()
    if not page.names:
        raise SystemExit(f"{path}: no NAME section naming the page (texsyn-x - what it does)")
    return text, page.names


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", required=True, type=Path, help="directory of the NAME.1 files")
    ap.add_argument("pages", nargs="+", type=Path)
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    for path in args.pages:
        text, names = convert(path)
        (args.out / f"{path.stem}.1").write_text(text)
        for alias in names:
            if alias != path.stem:
                (args.out / f"{alias}.1").write_text(f".so man1/{path.stem}.1\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())

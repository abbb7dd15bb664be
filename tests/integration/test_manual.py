"""The manual: the README stays short, every command has a page whose
generated options block is what the command's --help prints (doc/gen.py),
every page converts to a man page that man renders without a warning
(doc/md2man.py), and no relative link in any tracked .md file is dead."""
import os
import re
import subprocess
import sys
import urllib.parse
from pathlib import Path

import pytest

from conftest import BUILD, REPO

sys.path.insert(0, str(REPO / "doc"))
import gen  # noqa: E402
import md2man  # noqa: E402

README_MAX = 15 * 1024
PAGES = gen.pages()


def test_readme_is_short():
    size = (REPO / "README.md").stat().st_size
    assert size <= README_MAX, (f"README.md is {size} bytes, over {README_MAX}: move the detail to a page "
                                "in doc/ or to the guide beside its code, and link it")


def test_readme_keeps_the_two_commands():
    text = (REPO / "README.md").read_text()
    for cmd in ("make demo", "make test"):
        assert f"\n{cmd}" in text, f"README.md lost its `{cmd}` line"


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_page_options_are_the_programs_help(page):
    blocks = gen.blocks(page.read_text())
    if page.name != "texsyn-simd.md":  # simd has no options: it prints the CPU's kernels
        assert blocks, f"{page.name} has no <!-- options: ... --> block"
    for cmd, body in blocks:
        want = gen.block_body(gen.help_text(cmd, BUILD))
        assert body == want, f"doc/{page.name} is stale: run make doc (`{cmd}` prints something else)"


def test_every_command_has_a_page():
    """Each command `texsyn --help` lists is named by some page's NAME
    section (texsyn-status by texsyn-jobs.md), so `man texsyn-CMD` opens it."""
    listed = re.findall(r"^  ([a-z][a-z-]*)\s", gen.help_text("texsyn --help", BUILD), re.M)
    assert "synth" in listed and "status" in listed, "texsyn --help no longer lists commands as `  NAME  what`"
    named = set()
    for page in PAGES:
        named.update(md2man.convert(page)[1])
    missing = [c for c in listed if f"texsyn-{c}" not in named and c != "help"]  # help: this list, texsyn(1)
    assert not missing, f"no page in doc/ names texsyn-{', texsyn-'.join(missing)} in its NAME section"


def render(path, locale="C.UTF-8"):
    env = dict(os.environ, MANWIDTH="80", LC_ALL=locale)
    p = subprocess.run(["man", "--warnings", "-l", str(path)], capture_output=True, text=True, env=env,
                       timeout=60)
    return p.returncode, p.stdout, p.stderr


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_page_renders_as_a_man_page(page, tmp_path):
    text, names = md2man.convert(page)
    man = tmp_path / f"{page.stem}.1"
    man.write_text(text)
    for locale in ("C", "C.UTF-8"):  # an ASCII terminal lacks glyphs a UTF-8 one has
        rc, out, err = render(man, locale)
        assert rc == 0 and not err, f"man -l on {page.name}'s man page, LC_ALL={locale}: status {rc}\n{err}"
    assert re.search(rf"^NAME\n\s+{re.escape(names[0])}\b", out, re.M), out[:400]
    assert "SEE ALSO" in out
    # An option of its help block, with its hyphens as typed (not turned
    # into U+2010 hyphens, which a search for the option would miss).
    blocks = gen.blocks(page.read_text())
    options = [m.group(1) for _, body in blocks
               if (m := re.search(r"^\s+(--[a-z-]+)", body, re.M) or re.search(r"(--[a-z-]+)", body))]
    assert options or not blocks, f"{page.name}: no --option in its generated blocks"
    for option in options:
        assert option in out, f"{page.name}: {option} not in\n{out}"


def test_man_page_converter_can_fail(tmp_path):
    page = tmp_path / "texsyn-x.md"
    page.write_text("# texsyn-y(1)\n\n## NAME\n\ntexsyn-x - a test\n")
    with pytest.raises(SystemExit, match="title: # texsyn-x"):
        md2man.convert(page)
    page.write_text("# texsyn-x(1)\n\n## NAME\n\ntexsyn-x - a test\n\n```sh\nls\n")
    with pytest.raises(SystemExit, match="code block is not closed"):
        md2man.convert(page)


def test_a_stale_page_is_found(tmp_path):
    page = tmp_path / "texsyn-shuffle.md"
    page.write_text("<!-- options: texsyn shuffle --help -->\n```text\nold\n```\n<!-- /options -->\n")
    p = subprocess.run([sys.executable, str(REPO / "doc" / "gen.py"), "--build", str(BUILD), "--check", str(page)],
                       capture_output=True, text=True)
    assert p.returncode == 1 and f"{page} is stale: run make doc" in p.stderr, p.stderr
    subprocess.run([sys.executable, str(REPO / "doc" / "gen.py"), "--build", str(BUILD), str(page)], check=True,
                   capture_output=True)
    assert "usage: texsyn shuffle" in page.read_text()


def test_make_install_puts_the_man_pages_where_man_finds_them(tmp_path):
    """`make install` converts the pages and installs them with a stub per
    further name: man finds texsyn-synth and, through its stub, texsyn-watch."""
    prefix = tmp_path / "usr"
    p = subprocess.run(["make", "-s", f"BUILD={BUILD}", f"PREFIX={prefix}", "install-man"], cwd=REPO,
                       capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stdout + p.stderr
    env = dict(os.environ, MANWIDTH="80", LC_ALL="C.UTF-8")
    for name, says in (("texsyn-synth", "--ref IMG"), ("texsyn-watch", "texsyn watch ID")):
        out = subprocess.run(["man", "-M", str(prefix / "share" / "man"), name], capture_output=True, text=True,
                             env=env, timeout=60)
        assert out.returncode == 0 and says in out.stdout, f"man {name}: {out.stderr}{out.stdout[:300]}"


# --- links -----------------------------------------------------------------

LINK = re.compile(r"!?\[[^\]]*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
REF_DEF = re.compile(r"^\s{0,3}\[[^\]]+\]:\s+(\S+)", re.M)
IMG_SRC = re.compile(r"<img\s[^>]*src=\"([^\"]+)\"")


def tracked_markdown():
    p = subprocess.run(["git", "ls-files", "-z", "*.md"], cwd=REPO, capture_output=True, text=True)
    if p.returncode == 0:
        return [REPO / f for f in p.stdout.split("\0") if f]
    return [f for f in REPO.rglob("*.md") if not any(part.startswith(("build", ".")) for part in f.parts)]


def without_code_blocks(text):
    return re.sub(r"^( *)(```|~~~).*?^\1\2", "", text, flags=re.M | re.S)


def prose(text):
    """The text without code blocks and code spans, where a [x](y) is code."""
    return re.sub(r"`[^`\n]*`", "", without_code_blocks(text))


def slug(heading):
    """The anchor GitHub gives a heading."""
    s = re.sub(r"!?\[([^\]]*)\]\([^)]*\)", r"\1", heading.strip()).lower()
    s = re.sub(r"[^\w\- ]", "", s)
    return s.replace(" ", "-")


def anchors(path):
    seen, out = {}, set()
    for h in re.findall(r"^#{1,6}\s+(.*?)\s*#*\s*$", without_code_blocks(path.read_text()), re.M):
        s = slug(h)
        out.add(s if s not in seen else f"{s}-{seen[s]}")
        seen[s] = seen.get(s, 0) + 1
    out.update(re.findall(r"<a\s+(?:name|id)=\"([^\"]+)\"", path.read_text()))
    return out


def dead_links(path):
    """(link, what is wrong) for every relative link of a .md file that leads
    nowhere: a missing file or directory, or an anchor no heading has."""
    text = prose(path.read_text())
    dead = []
    for target in LINK.findall(text) + REF_DEF.findall(text) + IMG_SRC.findall(text):
        if re.match(r"^[a-z][a-z0-9+.-]*:", target, re.I):  # http:, mailto:, ...
            continue
        file, _, anchor = urllib.parse.unquote(target).partition("#")
        dest = (path.parent / file).resolve() if file else path
        if not dest.exists():
            dead.append((target, f"{dest.relative_to(REPO) if dest.is_relative_to(REPO) else dest} does not exist"))
        elif anchor and dest.suffix == ".md" and anchor not in anchors(dest):
            dead.append((target, f"{dest.name} has no heading #{anchor}"))
    return dead


def test_no_dead_relative_links():
    dead = [f"{path.relative_to(REPO)}: ({link}) {why}" for path in tracked_markdown() for link, why in dead_links(path)]
    assert not dead, "dead links:\n" + "\n".join(dead)


def test_a_dead_link_is_found(tmp_path):
    (tmp_path / "there.md").write_text("# A heading (`--opt`)\n")
    page = tmp_path / "page.md"
    page.write_text("[ok](there.md#a-heading---opt) [gone](nowhere.md) [bad](there.md#nope) "
                    "`[code](skipped.md)` [web](https://example.org/x)\n")
    assert dead_links(page) == [("nowhere.md", f"{tmp_path / 'nowhere.md'} does not exist"),
                                ("there.md#nope", "there.md has no heading #nope")]

#!/usr/bin/python3
"""The benchmarks' one plotting helper: writes a gnuplot script and its
data file beside the picture (OUT/gnuplot/NAME.gp, NAME.dat, with paths
relative to OUT, so a plot can be restyled and redrawn with
`cd OUT && gnuplot gnuplot/NAME.gp` without rerunning the benchmark) and
runs gnuplot there (Debian gnuplot-nox, pngcairo terminal).

Two kinds of chart:
  lines(png, series, ...)  lines/points over numeric x, optional log axes,
                           error bars from each point's spread (lo, hi),
                           vertical/horizontal marks (a core count, a roof);
  bars(png, groups, ...)   clustered bars, one cluster per category, one bar
                           per group, optional error bars (lo, hi).

A missing gnuplot does not fail a benchmark: its tables are the result,
the picture is an illustration. The message says how to get it.
"""
import shutil
import subprocess
from pathlib import Path

TERMINAL = "set terminal pngcairo size {w},{h} enhanced font 'DejaVu Sans,10'"


class Series:
    """One line: points are (x, y) or (x, y, lo, hi) with lo/hi the spread
    of y (drawn as error bars). style: a gnuplot 'with' clause."""

    def __init__(self, title, points, style="linespoints", options=""):
        self.title, self.points, self.style, self.options = title, list(points), style, options

    def has_spread(self):
        return bool(self.points) and all(len(p) == 4 for p in self.points)


def quoted(text):
    """A gnuplot string literal (single quotes: no escapes inside)."""
    return "'" + str(text).replace("'", "''") + "'"


def _files(png):
    png = Path(png)
    d = png.parent / "gnuplot"
    d.mkdir(parents=True, exist_ok=True)
    return png, d / (png.stem + ".gp"), d / (png.stem + ".dat")


def _rel(path):
    """A file's path as the script names it: relative to the picture's folder."""
    return f"gnuplot/{path.name}"


def _header(png, title, xlabel, ylabel, size, logx, logy):
    out = [TERMINAL.format(w=size[0], h=size[1]), f"set output {quoted(png.name)}",
           f"set title {quoted(title)}", f"set xlabel {quoted(xlabel)}", f"set ylabel {quoted(ylabel)}",
           "set grid", "set key top left box opaque", "set datafile separator '\\t'"]
    if logx:
        out.append("set logscale x")
    if logy:
        out.append("set logscale y")
    return out


def _marks(marks):
    """('x', value, label) draws a vertical dashed line at x=value,
    ('y', value, label) a horizontal one."""
    out = []
    for axis, value, label in marks or ():
        if axis == "x":
            out.append(f"set arrow from {value}, graph 0 to {value}, graph 1 nohead dt 2 lc rgb 'gray40'")
            out.append(f"set label {quoted(label)} at {value}, graph 0.95 offset 0.5,0 textcolor rgb 'gray30'")
        else:
            out.append(f"set arrow from graph 0, first {value} to graph 1, first {value} nohead dt 2 lc rgb 'gray40'")
            out.append(f"set label {quoted(label)} at graph 0.02, first {value} offset 0,0.6 textcolor rgb 'gray30'")
    return out


def _run(script, gp, name):
    gp.write_text("\n".join(script) + "\n")
    if shutil.which("gnuplot") is None:
        print(f"bench: gnuplot missing, no plot {name} (deploy/install-deps.sh --bench installs gnuplot-nox)")
        return False
    p = subprocess.run(["gnuplot", _rel(gp)], capture_output=True, text=True, cwd=gp.parent.parent)
    if p.returncode != 0:
        print(f"bench: gnuplot failed on {gp}, no plot {name}:\n{p.stderr}")
        return False
    return True


def lines(png, series, title, xlabel, ylabel, logx=False, logy=False, marks=(), xtics=None,
          size=(800, 500), extra=()):
    """Draws series (a list of Series) into png; returns whether it did.
    xtics: the x values to label (e.g. the worker counts); extra: more
    gnuplot commands before the plot (set key, set yrange ...)."""
    png, gp, dat = _files(png)
    blocks = []
    for s in series:
        blocks.append("\n".join("\t".join(f"{v:.6g}" for v in p) for p in s.points))
    dat.write_text("\n\n\n".join(blocks) + "\n")  # one gnuplot index per series
    script = _header(png, title, xlabel, ylabel, size, logx, logy) + _marks(marks)
    if xtics:
        script.append("set xtics (" + ", ".join(f"{quoted(x)} {x}" for x in xtics) + ")")
    script += list(extra)
    parts = []
    for i, s in enumerate(series):
        if s.has_spread():
            style = "yerrorlines" if "lines" in s.style else "yerrorbars"
            parts.append(f"{quoted(_rel(dat))} index {i} using 1:2:3:4 with {style} {s.options} "
                         f"title {quoted(s.title)}")
        else:
            parts.append(f"{quoted(_rel(dat))} index {i} using 1:2 with {s.style} {s.options} title {quoted(s.title)}")
    script.append("plot " + ", \\\n     ".join(parts))
    return _run(script, gp, png.name)


def bars(png, categories, groups, title, ylabel, spreads=None, logy=False, size=(800, 500), extra=()):
    """Clustered bars: categories label the clusters along x; groups maps a
    bar's legend to its values, one per category; spreads (optional) maps
    the same legends to (lo, hi) per category, drawn as error bars."""
    png, gp, dat = _files(png)
    names = list(groups)
    rows = []
    for i, c in enumerate(categories):
        cells = [str(c)]
        for n in names:
            v = groups[n][i]
            lo, hi = spreads[n][i] if spreads else (v, v)
            cells += [f"{v:.6g}", f"{lo:.6g}", f"{hi:.6g}"]
        rows.append("\t".join(cells))
    dat.write_text("\n".join(rows) + "\n")
    script = _header(png, title, "", ylabel, size, False, logy)
    script += ["set style data histogram", "set style histogram errorbars gap 1 lw 1",
               "set style fill solid 0.7 border -1", "set boxwidth 0.9", "set xtics nomirror",
               "set key top left", "set yrange [0:*]" if not logy else "set yrange [*:*]", *extra]
    parts = [f"{quoted(_rel(dat))} using {2 + 3 * k}:{3 + 3 * k}:{4 + 3 * k}:xtic(1) title {quoted(n)}"
             for k, n in enumerate(names)]
    script.append("plot " + ", \\\n     ".join(parts))
    return _run(script, gp, png.name)

"""The benchmark suite's own tools, on made-up inputs (no benchmark runs):
the gnuplot helper's scripts and data, the roofline's classification, the
scaling arithmetic and RESULTS.md's assembly (missing, stale and stamped
sections)."""
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parents[2] / "bench"
sys.path.insert(0, str(BENCH))
import gnuplot  # noqa: E402
from pnm import pixels_of  # noqa: E402
import roofline  # noqa: E402
import scaling  # noqa: E402

PY = "/usr/bin/python3"


def drew(png, ok, tmp):
    """The picture exists exactly when gnuplot is installed, and then it
    is a PNG of the size asked (gnuplot's 800x500 default here) with the
    plot in it: gnuplot writes a picture of axes and key alone when the
    data misses the axes' ranges (or an empty file when it fails mid-way),
    which only the pixels tell. The axes, text and key are grey or black,
    a key sample line tens of coloured pixels: the series' lines and bars
    are the hundreds more."""
    if not shutil.which("gnuplot"):
        assert not ok and not png.exists()
        return
    assert ok and png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    w, h, ch, px = pixels_of(png, tmp)
    assert (w, h, ch) == (800, 500, 3), (w, h, ch)
    coloured = sum(1 for i in range(0, len(px), ch) if max(px[i:i + ch]) - min(px[i:i + ch]) > 60)
    assert coloured >= 300, f"{png}: {coloured} coloured pixels, the series are not drawn"


def test_lines_writes_spread_log_axes_and_marks(tmp_path):
    png = tmp_path / "s.png"
    ok = gnuplot.lines(png, [gnuplot.Series("ideal", [(1, 1), (2, 2)], "lines"),
                             gnuplot.Series("job's", [(1, 1.0, 0.9, 1.1), (2, 1.8, 1.7, 1.95)])],
                       "speed-up", "workers", "x", logx=True, logy=True, marks=[("x", 2, "2 cores")], xtics=[1, 2])
    gp = (tmp_path / "gnuplot" / "s.gp").read_text()
    dat = (tmp_path / "gnuplot" / "s.dat").read_text()
    assert "set logscale x" in gp and "set logscale y" in gp
    assert "index 1 using 1:2:3:4 with yerrorlines" in gp and "title 'job''s'" in gp
    assert "set arrow from 2, graph 0 to 2, graph 1" in gp and "set xtics ('1' 1, '2' 2)" in gp
    assert dat.split("\n\n\n")[1].splitlines() == ["1\t1\t0.9\t1.1", "2\t1.8\t1.7\t1.95"]
    drew(png, ok, tmp_path)


def test_bars_writes_one_row_per_category_with_spreads(tmp_path):
    png = tmp_path / "b.png"
    ok = gnuplot.bars(png, ["L1", "L0"], {"ours": [1, 2], "seed": [3, 4]}, "t", "s",
                      spreads={"ours": [(0.5, 1.5), (2, 2.5)], "seed": [(3, 3), (4, 4)]})
    gp = (tmp_path / "gnuplot" / "b.gp").read_text()
    rows = (tmp_path / "gnuplot" / "b.dat").read_text().splitlines()
    assert "set style histogram errorbars" in gp and "using 5:6:7:xtic(1) title 'seed'" in gp
    assert rows == ["L1\t1\t0.5\t1.5\t3\t3\t3", "L0\t2\t2\t2.5\t4\t4\t4"]
    drew(png, ok, tmp_path)


def kernels_csv(path, memread=True):
    rows = ["variant,kind,where,nq,nchunks,gbps,pairs_per_s,bytes_per_cycle"]
    if memread:
        rows.append("fast,memread-1t,mem,0,0,20.0,0,5")
    for v, cache, mem in (("slow", 5.0, 5.0), ("fast", 60.0, 18.0)):
        rows += [f"{v},single,cache,1,7,{cache},0,0", f"{v},single,mem,1,7,{mem},0,0",
                 f"{v},batch,cache,32,7,{cache},0,0", f"{v},batch,mem,32,7,{cache},0,0",
                 f"{v},single,cache,1,12,1.0,0,0"]
    path.write_text("\n".join(rows) + "\n")


def test_roofline_tells_memory_from_compute_bound(tmp_path):
    kernels_csv(tmp_path / "kernels.csv")
    bw, kern = roofline.load(tmp_path / "kernels.csv")
    cls = roofline.classify(bw, kern)
    assert cls["slow"]["bound"] == "compute"  # as fast from DRAM as from L2
    assert cls["fast"]["bound"] == "memory"   # slower from DRAM, at 90% of the bandwidth
    assert cls["fast"]["share_of_bandwidth"] == pytest.approx(0.9)
    assert cls["fast"]["batch_nq"] == 32


def test_roofline_refuses_a_csv_without_the_bandwidth(tmp_path):
    kernels_csv(tmp_path / "kernels.csv", memread=False)
    p = subprocess.run([PY, BENCH / "roofline.py", "--out", tmp_path], capture_output=True, text=True)
    assert p.returncode != 0 and "no memread-1t row" in p.stderr


def test_scaling_speedup_and_efficiency_from_medians():
    def runs(*walls, same=True):
        return [{"wall": w, "identical": same, "coordinator_cpu": 1.0, "workers_cpu": 2.0, "levels": {"0": w}}
                for w in walls]
    rows = scaling.summarize({"embedded": runs(9, 9, 9), "1": runs(10, 12, 11), "2": runs(6, 5.5, 8, same=False)},
                             [1, 2])
    by = {r["label"]: r for r in rows}
    assert "speedup" not in by["embedded"]
    assert by["1"]["speedup"] == 1.0 and by["1"]["spread_s"] == [10, 12]
    assert by["2"]["speedup"] == pytest.approx(11 / 6) and by["2"]["efficiency"] == pytest.approx(11 / 12)
    assert by["2"]["speedup_spread"] == pytest.approx([11 / 8, 2.0])
    assert by["1"]["identical"] and not by["2"]["identical"]


def test_results_md_missing_stamped_and_unstamped_sections(tmp_path):
    md = tmp_path / "RESULTS.md"
    subprocess.run([PY, BENCH / "results_md.py", "--out", tmp_path], check=True, capture_output=True)
    text = md.read_text()
    assert f"**{os.cpu_count()} cores** (nproc)" in text
    assert "**Not measured**: table33.md, table33.json missing" in text
    assert "It needs the Ebsynth peer" in text

    (tmp_path / "table33.md").write_text("# Table 3.3\n\n| level | s |\n|---|---|\n| 0 | 1.5 |\n")
    (tmp_path / "table33.json").write_text(json.dumps({"totals": {}}))
    (tmp_path / "lbg.md").write_text("# LBG\n")
    (tmp_path / "lbg.json").write_text("{}")
    subprocess.run([PY, BENCH / "results_md.py", "--out", tmp_path, "--stamp", "table33", "--mode", "full"],
                   check=True, capture_output=True)
    subprocess.run([PY, BENCH / "results_md.py", "--out", tmp_path], check=True, capture_output=True)
    text = md.read_text()
    t33 = text.split("## The seed's Table 3.3")[1].split("\n## ")[0]
    assert "(full mode" in t33 and "### Table 3.3" in t33 and "| 0 | 1.5 |" in t33
    assert "![The seed's Table 3.3, column by column: table33.png](table33.png)" not in t33
    assert "Plot table33.png missing" in t33
    lbg = text.split("## LBG partitioning")[1].split("\n## ")[0]
    assert "possibly stale" in lbg

    p = subprocess.run([PY, BENCH / "results_md.py", "--out", tmp_path, "--stamp", "nosuch"],
                       capture_output=True, text=True)
    assert p.returncode != 0 and "unknown section 'nosuch'" in p.stderr


def test_table33_extrapolates_the_scalar_levels_from_the_exhaustive_count():
    import table33

    def lv(seconds, blocks, vectors, comparisons=None):
        return {"seconds": seconds, "spread": [seconds, seconds], "blocks": blocks, "vectors": vectors,
                "comparisons": blocks * vectors if comparisons is None else comparisons, "measured": True}
    basis = {4: lv(0.01, 10, 10), 3: lv(0.1, 40, 40), 2: lv(1.0, 100, 1000)}
    simd = {**{l: lv(0.001, 100, 1000) for l in (4, 3, 2)}, 1: lv(0.01, 400, 4000), 0: lv(0.1, 1600, 16000)}
    rate = table33.extrapolate(basis, table33.exhaustive(basis, simd))
    assert rate == 100000.0  # level 2: 100 x 1000 comparisons in 1 s
    assert basis[1] == {"seconds": 16.0, "spread": [16.0, 16.0], "comparisons": 1600000, "measured": False}
    assert basis[0]["seconds"] == 256.0 and basis[2]["measured"]
    with pytest.raises(SystemExit, match="not blocks x vectors"):
        table33.exhaustive({2: lv(1.0, 100, 1000, comparisons=25000)}, simd)


def test_roofline_calls_a_batch_compute_bound_below_its_roof(tmp_path):
    kernels_csv(tmp_path / "kernels.csv")
    cls = roofline.classify(*roofline.load(tmp_path / "kernels.csv"))
    # fast's batch of 32: 60 GB/s compared is 1.9 GB/s read, far below 20 GB/s
    assert cls["fast"]["batch_bound"] == "compute" and cls["fast"]["batch_dram_loss"] == 0

"""Fetching a result larger than an 'F' reply holds inline (proto/msg.h,
TS_FETCH_INLINE: 16 MiB): the reply names it with its size and the client
takes it in 'B' ranges of at most 16 MiB into a temporary file, so neither
the coordinator nor the client holds it whole, and results past 4 GiB
travel. Here an 18 MB raw copy map (2 ranges) comes back with the
embedded run's bytes, beside the small image that came inline."""
from conftest import BUILD, run

ARGS = ("--size", "1500x1500", "--levels", "1", "--wb", "9", "--wn", "11", "--quiet")


def test_a_result_past_the_inline_limit_comes_in_ranges(data, cluster, tmp_path):
    ref = data / "textures" / "brick.png"
    run(BUILD / "texsyn", "synth", "--ref", ref, "-o", tmp_path / "e.png", "--copy-map-raw", tmp_path / "e.raw",
        *ARGS)
    assert (tmp_path / "e.raw").stat().st_size == 1500 * 1500 * 8 > 16 << 20
    cluster.start(1, 1)
    cluster.texsyn("synth", "--ref", ref, "-o", tmp_path / "c.png", "--copy-map-raw", tmp_path / "c.raw", *ARGS)
    assert (tmp_path / "c.raw").read_bytes() == (tmp_path / "e.raw").read_bytes()
    assert (tmp_path / "c.png").read_bytes() == (tmp_path / "e.png").read_bytes()
    assert not list(tmp_path.glob("*.tmp*")), "a temporary file left behind"

"""Bad input gets one clear error naming what is wrong, never a crash."""
import pytest

from conftest import run


@pytest.mark.sanitize
def test_missing_reference_names_the_file(texsyn, tmp_path):
    p = run(texsyn, "synth", "--ref", tmp_path / "nope.png", "-o", tmp_path / "o.png",
            "--size", "64x64", check=False)
    assert p.returncode == 1
    assert "nope.png" in p.stderr


@pytest.mark.sanitize
def test_garbage_and_truncated_references(texsyn, data, tmp_path):
    bad = tmp_path / "bad.png"
    bad.write_bytes(b"this is not an image at all")
    cut = tmp_path / "cut.png"
    cut.write_bytes((data / "textures" / "brick.png").read_bytes()[:5000])
    for f in (bad, cut):
        p = run(texsyn, "synth", "--ref", f, "-o", tmp_path / "o.png", "--size", "64x64", check=False)
        assert p.returncode == 1, p.stderr
        assert f.name in p.stderr
        assert not (tmp_path / "o.png").exists()


@pytest.mark.sanitize
def test_all_parameter_problems_listed_at_once(texsyn, data, tmp_path):
    p = run(texsyn, "synth", "--ref", data / "textures" / "brick.png", "-o", tmp_path / "o.png",
            "--size", "64x64", "--wb", "4", "--wn", "2", "--levels", "0", check=False)
    assert p.returncode == 2
    for needle in ("--wb 4", "--wn 2", "--levels 0"):
        assert needle in p.stderr


@pytest.mark.sanitize
def test_too_many_levels_for_the_size(texsyn, data, tmp_path):
    p = run(texsyn, "synth", "--ref", data / "textures" / "brick.png", "-o", tmp_path / "o.png",
            "--size", "64x64", "--levels", "8", check=False)
    assert p.returncode == 2
    assert "coarsest level" in p.stderr and "fewer levels" in p.stderr


@pytest.mark.sanitize
@pytest.mark.parametrize("args,needle", [
    (["--size", "64by64"], "--size"),
    (["--size", "64x64", "--threads", "0"], "--threads"),
    (["--size", "64x64", "--seed", "-3"], "--seed"),
    (["--size", "64x64", "--bogus"], "--bogus"),
    (["--size", "64x64", "--usage-weight", "abc"], "--usage-weight"),
])
def test_malformed_options(texsyn, data, tmp_path, args, needle):
    p = run(texsyn, "synth", "--ref", data / "textures" / "brick.png", "-o", tmp_path / "o.png",
            *args, check=False)
    assert p.returncode == 2
    assert needle in p.stderr


@pytest.mark.sanitize
def test_output_over_pixel_limit(texsyn, data, tmp_path):
    p = run(texsyn, "synth", "--ref", data / "textures" / "brick.png", "-o", tmp_path / "o.png",
            "--size", "100000x100000", check=False)
    assert p.returncode == 2
    assert "--max-pixels" in p.stderr


@pytest.mark.sanitize
def test_help_documents_every_option(texsyn):
    p = run(texsyn, "synth", "--help")
    for opt in ("--ref", "--size", "--levels", "--wn", "--wb", "--parity", "--usage-weight",
                "--seed", "--copy-map", "--usage-map", "--threads", "--rgb-search", "--max-pixels"):
        assert opt in p.stdout
    assert "default 5" in p.stdout and "default 7" in p.stdout and "default 3" in p.stdout

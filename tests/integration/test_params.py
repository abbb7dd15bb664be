"""Each engine's parameters are declared once (server/engines/param.h): the
command line's options and --help come from that table. These hold every
command's --help to the table `texsyn params` prints: each declared option
is offered and described with its default."""
import json
import os
import re

import pytest

from conftest import run

# The command that runs each engine, as a newcomer types it.
COMMANDS = {
    "mrf": ["synth"],
    "fill": ["synth", "--input", "x.png"],
    "aerial": ["aerial"],
    "stylize": ["stylize"],
    "energy": ["energy"],
    "segment": ["segment"],
}


# Commands with a parameter table of their own, beside their engine's.
COMMAND_TABLES = {"video": ["video"]}


def table(texsyn, engine, kind="engine"):
    """(key, option, default) of each parameter `texsyn params ENGINE` lists."""
    out = run(texsyn, "params", engine).stdout.splitlines()
    assert out[0] == f"{kind} {engine}", out
    rows = [re.match(r"  (\S+)\s+(\S+)\s+(\S+)\s", line) for line in out[1:]]
    assert all(rows), out
    return [r.groups() for r in rows]


@pytest.mark.sanitize
@pytest.mark.parametrize("engine", sorted(COMMANDS))
def test_every_declared_option_is_in_the_commands_help(texsyn, engine):
    help_text = run(texsyn, *COMMANDS[engine], "--help").stdout
    options = [(key, opt, default) for key, opt, default in table(texsyn, engine) if opt != "-"]
    assert options, engine
    for key, opt, default in options:
        # The option's line, and its help up to the next option.
        m = re.search(rf"^  {re.escape(opt)}\b(.*?)(?=^  -|\Z)", help_text, re.S | re.M)
        assert m, f"{opt} ({engine}.{key}) is not in texsyn {' '.join(COMMANDS[engine])} --help"
        text = " ".join(m.group(1).split())
        if default != "-":
            assert re.search(r"[(;] ?default ", text), f"{opt}: no default in --help: {text}"


@pytest.mark.parametrize("command", sorted(COMMAND_TABLES))
def test_a_commands_own_table_is_in_its_help(texsyn, command):
    """texsyn video's guide weights are declared once too: each is offered
    with its range and default, and the range is enforced from the table."""
    help_text = run(texsyn, *COMMAND_TABLES[command], "--help").stdout
    rows = table(texsyn, command, kind="command")
    assert rows, command
    for key, opt, default in rows:
        m = re.search(rf"^  {re.escape(opt)}\b(.*?)(?=^  -|\Z)", help_text, re.S | re.M)
        assert m, f"{opt} ({command}.{key}) is not in texsyn {command} --help"
        assert f"default {default})" in " ".join(m.group(1).split()), m.group(1)


def test_params_lists_every_engine_and_refuses_an_unknown_one(texsyn):
    out = run(texsyn, "params").stdout
    assert re.findall(r"^engine (\S+)", out, re.M) == ["mrf", "stylize", "energy", "fill", "aerial", "segment"]
    assert re.findall(r"^command (\S+)", out, re.M) == sorted(COMMAND_TABLES)
    p = run(texsyn, "params", "nope", check=False)
    assert p.returncode == 2 and "no engine or command 'nope'" in p.stderr, p.stderr


def test_a_spec_only_key_is_no_option(texsyn):
    """pairs and truth follow from the inputs given: never an option."""
    rows = {key: opt for key, opt, _ in table(texsyn, "segment")}
    assert rows["pairs"] == "-" and rows["truth"] == "-"
    p = run(texsyn, "segment", "--pairs", "2", check=False)
    assert p.returncode == 2 and "--pairs" in p.stderr, p.stderr


def test_a_small_size_takes_as_many_default_levels_as_it_holds(texsyn, data, tmp_path):
    """The help says any size: 64x64 holds 4 levels of a 7-wide window, and
    without --levels it takes them; an explicit --levels 5 is refused."""
    ref = data / "textures" / "brick.png"
    out, report = tmp_path / "s.png", tmp_path / "r.json"
    run(texsyn, "synth", "--embedded", "--ref", ref, "--size", "64x64", "-o", out, "--report", report)
    assert json.loads(report.read_text())["params"]["levels"] == 4
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    p = run(texsyn, "synth", "--embedded", "--ref", ref, "--size", "64x64", "--levels", "5", "-o", out, check=False)
    assert p.returncode == 2 and "--levels 5: the output is only 4x4 at the coarsest level" in p.stderr, p.stderr


def test_threads_default_to_the_online_cpus(texsyn, data, tmp_path):
    """Without --threads an in-process job scans on every online CPU, as a
    worker does; the closing line says how many."""
    p = run(texsyn, "synth", "--embedded", "--ref", data / "textures" / "brick.png", "--size", "64x64",
            "-o", tmp_path / "t.png")
    assert f"in-process with {os.cpu_count()} threads" in p.stderr, p.stderr

"""The one command-line pattern: the ``courtside`` dispatcher and the shared argparse types."""

import argparse
import importlib
import subprocess
import sys
from pathlib import Path

import pytest

from capture import cli, cliargs

NAME = "expelliarmus_evt3_pedestrians_cut_1280x720.raw"


def test_courtside_subcommand_is_the_module_command(shared_raw_dir, capsys):
    assert cli.main(["raw", "info", str(shared_raw_dir / NAME)]) == 0
    via_courtside = capsys.readouterr().out
    assert importlib.import_module("capture.raw.cli").main(["info", str(shared_raw_dir / NAME)]) == 0
    assert capsys.readouterr().out == via_courtside and "events: 5000" in via_courtside


def test_courtside_lists_commands_and_rejects_unknown_ones(capsys):
    assert cli.main(["--help"]) == 0
    out = capsys.readouterr().out
    assert all(name in out for name in cli.COMMANDS)
    assert cli.main(["fly"]) == 2
    assert "unknown command 'fly'" in capsys.readouterr().err
    assert cli.main([]) == 2


@pytest.mark.parametrize("name", sorted(cli.COMMANDS))
def test_every_command_follows_the_pattern(name):
    module = importlib.import_module(cli.COMMANDS[name][0])
    parser = module.build_parser()
    assert parser.prog.startswith("python -m ")
    with pytest.raises(SystemExit) as exit_:
        module.main(["--help"])
    assert exit_.value.code == 0


def test_installed_console_script_runs():
    script = Path(sys.executable).parent / "courtside"  # installed by pip next to the interpreter
    proc = subprocess.run([str(script), "--help"], capture_output=True, text=True)
    assert proc.returncode == 0 and "replay" in proc.stdout


def test_argument_types():
    assert cliargs.box("1,2,30,40") == (1, 2, 30, 40)
    assert cliargs.name_int("bias_fo=-5") == ("bias_fo", -5)
    assert cliargs.positive_int("3") == 3
    for fn, bad in ((cliargs.box, "1,2,3"), (cliargs.box, "1 2 3 4"), (cliargs.name_int, "bias_fo"),
                    (cliargs.name_int, "bias_fo=x"), (cliargs.positive_int, "0")):
        with pytest.raises(argparse.ArgumentTypeError):
            fn(bad)


def test_run_command_gives_one_line_and_exit_codes(capsys):
    def fails():
        raise FileNotFoundError("x.raw: no such RAW file\n(second line)")

    assert cliargs.run_command("python -m capture.thing", fails) == 1
    err = capsys.readouterr().err
    assert err == "capture.thing: error: x.raw: no such RAW file (second line)\n"
    assert cliargs.run_command("p", lambda: (_ for _ in ()).throw(KeyError("k"))) == 1
    assert capsys.readouterr().err == "p: error: KeyError: 'k'\n"  # a foreign error is named
    assert cliargs.run_command("p", lambda: (_ for _ in ()).throw(KeyboardInterrupt())) == 130
    assert cliargs.run_command("p", lambda: None) == 0 and cliargs.run_command("p", lambda: 3) == 3

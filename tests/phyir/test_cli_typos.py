"""A mistyped option is refused by the subcommand it was given to: the nearest option that command
has (difflib) and its own --help, not ``phyir --help``; a typo that leaves a required option unset
is named before the missing option."""

from __future__ import annotations

import pytest

from phyir.cli import main


def refused(argv: list[str], capsys) -> str:
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


@pytest.mark.parametrize("argv,command,typo,near", [
    (["predict", "in.hdr", "-o", "o.exr", "--lightning", "fused"], "predict", "--lightning", "--lighting"),
    (["predict", "in.hdr", "-o", "o.exr", "--net-sise=256x512"], "predict", "--net-sise", "--net-size"),
    (["eval", "--limt", "3"], "eval", "--limt", "--limit"),
    (["export", "scene.exr", "--gltf", "a.glb", "--ligths", "4"], "export", "--ligths", "--lights"),
    (["info", "a.exr", "--verbos"], "info", "--verbos", None),
    (["--verison"], None, "--verison", "--version"),
])
def test_a_mistyped_option_suggests_the_nearest_of_its_command(argv, command, typo, near, capsys):
    err = refused(argv, capsys)
    prog = f"phyir {command}" if command else "phyir"
    assert err.startswith(f"{prog}: error: unrecognized option {typo}")
    assert err.endswith(f"(see {prog} --help)")
    if near:
        assert f"did you mean {near}?" in err
    else:
        assert "did you mean" not in err


@pytest.mark.parametrize("argv,command,typo,near,required", [
    (["predict", "in.hdr", "--ouput", "o.exr"], "predict", "--ouput", "--output", "-o/--output"),
    (["insert", "room.exr", "--objct", "sphere", "-o", "o.exr"], "insert", "--objct", "--object", "--object"),
])
def test_a_typo_that_leaves_a_required_option_unset_is_named_first(argv, command, typo, near, required,
                                                                    capsys):
    err = refused(argv, capsys)
    head = f"phyir {command}: error: unrecognized option {typo} (did you mean {near}?)"
    assert err.startswith(head), err
    assert f"the following arguments are required: {required}" in err.removeprefix(head)
    assert err.endswith(f"(see phyir {command} --help)")


def test_what_is_not_a_typo_is_left_alone(capsys):
    # a required option missing and no typo: argparse's message, pointing at the subcommand's help
    err = refused(["predict", "in.hdr"], capsys)
    assert err == "phyir predict: error: the following arguments are required: -o/--output " \
                  "(see phyir predict --help)"
    # stray words (not options): argparse's words, the subcommand's help
    err = refused(["synth", "--out", "d", "--count", "1", "stray", "words"], capsys)
    assert err == "phyir synth: error: unrecognized arguments: stray words (see phyir synth --help)"
    # values that start with a minus are not options
    err = refused(["insert", "room.exr", "--object", "sphere", "--yaw", "-30", "--sclae", "2", "-o", "o.exr"],
                  capsys)
    assert err.startswith("phyir insert: error: unrecognized option --sclae (did you mean --scale?)")

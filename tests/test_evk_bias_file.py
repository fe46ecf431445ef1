"""Metavision .bias files: read, write, and applied by the recorder's command lines."""

import pytest

from capture.evk.bias_file import biases_of, read_bias_file, write_bias_file


def test_reads_metavision_layout(tmp_path):
    path = tmp_path / "tuned.bias"
    path.write_text("% Date 2024-01-01\n% serial_number 00050423\n"
                    "10   % bias_fo\n0x0A % bias_hpf\n-5   % bias_diff_on\n\n99 % ignored_after_blank\n")
    assert read_bias_file(path) == {"bias_fo": 10, "bias_hpf": 10, "bias_diff_on": -5}


@pytest.mark.parametrize("text, match", [("10 bias_fo\n", "wrong line format"), ("ten % bias_fo\n", "is not a number"),
                                         ("1 % bias_fo\n2 % bias_fo\n", "given two different values")])
def test_bad_files_are_refused_before_anything_is_set(tmp_path, text, match):
    path = tmp_path / "bad.bias"
    path.write_text(text)
    with pytest.raises(ValueError, match=match):
        read_bias_file(path)


def test_extension_and_round_trip(tmp_path):
    with pytest.raises(ValueError, match="expected the '.bias' extension"):
        read_bias_file(tmp_path / "x.txt")
    biases = {"bias_hpf": 5, "bias_fo": -3}
    path = write_bias_file(tmp_path / "out.bias", biases)
    assert path.read_text() == "-3   % bias_fo\n5    % bias_hpf\n"  # sorted by name, as Metavision saves
    assert read_bias_file(path) == biases
    assert biases_of(path, [("bias_fo", 7)]) == {"bias_fo": 7, "bias_hpf": 5}  # --bias overrides the file


def test_recording_applies_the_bias_file(shared_raw_dir, tmp_path, capsys):
    from capture.evk.cli import main as evk_main
    from capture.run import main as run_main
    from capture.session import open_session

    path = tmp_path / "tuned.bias"
    path.write_text("10 % bias_fo\n-20 % bias_diff_on\n")
    src = shared_raw_dir / "ros_codecs_evt3_trigger_1280x720.raw"
    assert run_main(["--fake", str(src), "--speed", "max", "--out", str(tmp_path / "s"), "--viewer", "none",
                     "--no-analysis", "--quiet", "--bias-file", str(path), "--bias", "bias_diff_on=-10"]) == 0
    biases = open_session(tmp_path / "s").attrs["sensor"]["biases"]
    assert biases["bias_fo"] == 10 and biases["bias_diff_on"] == -10 and biases["bias_hpf"] == 0
    capsys.readouterr()
    assert evk_main(["biases", "--fake", str(src), "--save", str(tmp_path / "saved.bias")]) == 0
    assert "bias_fo 0" in capsys.readouterr().out  # a fresh camera: factory values
    assert read_bias_file(tmp_path / "saved.bias") == dict.fromkeys(biases, 0)
    assert run_main(["--fake", str(src), "--out", str(tmp_path / "s2"), "--viewer", "none", "--no-analysis",
                     "--quiet", "--bias-file", str(tmp_path / "missing.bias")]) == 1
    assert "missing.bias" in capsys.readouterr().err

import json

import pytest

from lfring.cli.main import main

KEYS = {"ring_distance_m", "sensor_distance_m", "magnification", "image_height_m", "disparity_px",
        "overlap", "mount_distance_m", "entrance_pupil_m"}


def test_design_json(capsys):
    assert main(["design", "--object-size", "0.1", "--distance", "0.3", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert KEYS <= set(out)
    assert out["ring_distance_m"] == pytest.approx(37.369e-3, abs=1e-6)
    assert out["disparity_px"] == pytest.approx(383.07, abs=0.01)


def test_design_table_sweep_range_and_plots(tmp_path, capsys):
    assert main(["design", "--object-size", "0.1", "--distance", "0.3"]) == 0
    assert "37.369 mm" in capsys.readouterr().out
    png = tmp_path / "sweep.png"
    assert main(["design", "--object-size", "0.1", "--sweep", "0.1:2.0:12", "--plot", str(png)]) == 0
    out = capsys.readouterr()
    assert png.stat().st_size > 20_000 and png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "no overlap" in out.out  # invalid points are shown, not hidden
    assert main(["design", "--object-size", "0.1", "--range", "0.3:1.0", "--json"]) == 0
    rng = json.loads(capsys.readouterr().out)
    assert 0.3 < rng["focus_distance_m"] < 1.0 and len(rng["points"]) == 50
    # The same plot again replaces its own file; another one does not without --overwrite.
    assert main(["design", "--object-size", "0.1", "--sweep", "0.1:2.0:12", "--plot", str(png)]) == 0
    capsys.readouterr()
    assert main(["design", "--object-size", "0.1", "--sweep", "0.1:2.0:13", "--plot", str(png)]) == 2
    assert "exists" in capsys.readouterr().err


@pytest.mark.parametrize(
    "args, text",
    [
        (["--object-size", "-0.1", "--distance", "0.3"], "object size"),
        (["--object-size", "0.1", "--distance", "0.01"], "focal length"),
        (["--object-size", "0.1", "--distance", "0.3", "--device", "missing.toml"], "not found"),
        (["--object-size", "0.1", "--sweep", "0.1:2.0"], "Invalid value for --sweep: expected START:STOP:N, got '0.1:2.0'"),
        (["--object-size", "0.1", "--sweep", "0.3:1:0"], "Invalid value for --sweep: N must be >= 2, got 0"),
        (["--object-size", "0.1", "--sweep", "0.3:1:x"], "Invalid value for --sweep: N must be an integer, got 'x'"),
        (["--object-size", "0.1", "--sweep", "a:1:3"], "Invalid value for --sweep: START and STOP must be numbers"),
        (["--object-size", "0.1", "--range", "0.3"], "Invalid value for --range: expected NEAR:FAR, got '0.3'"),
        (["--object-size", "0.1", "--range", "a:1"], "Invalid value for --range: NEAR and FAR must be numbers"),
        (["--object-size", "0.1"], "exactly one of"),
        (["--object-size", "0.1", "--range", "1.0:0.3"], "far distance"),
    ],
)
def test_design_errors_are_one_clear_line(capsys, args, text):
    assert main(["design", *args]) == 2
    err = capsys.readouterr().err
    assert text in err and "Traceback" not in err


def test_range_words_are_the_helps(capsys):
    assert main(["design", "--help"]) == 0
    text = capsys.readouterr().out
    assert "--sweep START:STOP:N" in text and "--range NEAR:FAR" in text


@pytest.mark.parametrize("spec", [["--distance", "0.3"], ["--sweep", "0.3:1:3"], ["--range", "0.3:1.0"]])
@pytest.mark.parametrize("plot, text", [
    ("pl.txt", "Invalid value for --plot: the figure file must end in .png, .pdf, .svg, got 'pl.txt'"),
    ("pl.png", "pl.png exists; pass --overwrite"),
])
def test_plot_is_refused_before_the_numbers(tmp_path, capsys, spec, plot, text):
    (tmp_path / "pl.png").write_bytes(b"keep me")
    assert main(["design", "--object-size", "0.05", *spec, "--plot", str(tmp_path / plot)]) == 2
    out = capsys.readouterr()
    assert text in out.err and "Traceback" not in out.err
    assert out.out == ""  # nothing printed before the refusal
    assert (tmp_path / "pl.png").read_bytes() == b"keep me"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["pl.png"]


def test_malformed_device_file(tmp_path, capsys):
    bad = tmp_path / "dev.toml"
    bad.write_text("name = 'x'\nmain_focal_length_m = 0.016\n")
    assert main(["design", "--object-size", "0.1", "--distance", "0.3", "--device", str(bad)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "missing key" in err


def test_version(capsys):
    assert main(["--version"]) == 0
    assert "lfring, version" in capsys.readouterr().out


def test_a_plot_onto_an_input_names_plot(tmp_path, capsys):
    """The figure named as the --device file itself: refused naming --plot, the option to change."""
    same = tmp_path / "dev.png"
    same.write_bytes(b"not a device")
    assert main(["design", "--object-size", "0.05", "--distance", "0.3", "--plot", str(same), "--device", str(same)]) == 2
    err = capsys.readouterr().err
    assert "is an input of this command and would be one of its outputs (or their record): give --plot another name" in err
    assert same.read_bytes() == b"not a device"


def test_design_says_what_it_does_not_use(tmp_path, capsys):
    """A device set to its own positions is designed anew for the object and distance given (said,
    with the positions it holds); a device without a flange focal distance gets a mount distance B
    taken with 0 for it (warned: B was printed 17.5 mm short without a word)."""
    import dataclasses

    from lfring.optics import load_device, save_device

    assert main(["design", "--device", "prototype", "--object-size", "0.1", "--distance", "0.3"]) == 0
    err = capsys.readouterr().err
    assert "the positions device 'prototype' is set to (b 37.369 mm, c 6.616 mm) are not these" in err
    assert "flange_focal_distance_m" not in err
    dev = dataclasses.replace(load_device("prototype"), name="bare", flange_focal_distance_m=0.0, ring_distance_m=None,
                              sensor_distance_m=None)
    path = save_device(dev, tmp_path / "bare.toml")
    assert main(["design", "--device", str(path), "--object-size", "0.1", "--distance", "0.3"]) == 0
    err = capsys.readouterr().err
    assert "WARNING: device 'bare' gives no flange_focal_distance_m: the mount distance B below takes it as 0" in err
    assert "are not these" not in err

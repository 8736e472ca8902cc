"""`skyvln-eval convert` and `skyvln-eval validate` on MCAP files and folders."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from typer.testing import CliRunner

from skyvln_eval.cli import app
from skyvln_eval.converters.left_out import LEFT_OUT_NAME, LeftOut, write_left_out
from skyvln_eval.converters.manifest import MANIFEST_NAME
from skyvln_eval.errors import ConfigError
from tests.conftest import CliOutcome, make_record
from tests.converters.conftest import ConvertedSample

runner = CliRunner()


def test_convert_then_validate(converted_sample: ConvertedSample, tmp_path: Path) -> None:
    args = ["convert", "--data-dir", str(converted_sample.data_dir), "--split", "val_seen"]
    args += ["--out", str(tmp_path), "--mode", "andh-full", "--workers", "2"]
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    n = len(converted_sample.episodes[("val_seen", "andh-full")])
    assert f"{n} converted, 0 already converted (skipped), 0 failed" in result.output
    again = runner.invoke(app, args)
    assert f"0 converted, {n} already converted (skipped)" in again.output

    folder = tmp_path / "val_seen" / "andh-full"
    result = runner.invoke(app, ["validate", str(tmp_path)])
    assert result.exit_code == 0, result.output
    assert f"{n} MCAP file(s)" in result.output and "ok" in result.output

    one = sorted(folder.glob("*.mcap"))[0]
    result = runner.invoke(app, ["validate", str(one)])
    assert result.exit_code == 0 and "1 MCAP file(s)" in result.output

    # Damage one file and delete another: both are reported, by name, with exit 1.
    data = bytearray(one.read_bytes())
    data[len(data) // 2] ^= 0x10
    one.write_bytes(bytes(data))
    gone = sorted(folder.glob("*.mcap"))[1]
    gone.unlink()
    result = runner.invoke(app, ["validate", str(folder)])
    assert result.exit_code == 1
    assert f"{one}: damaged MCAP file" in result.output
    assert "content differs from the manifest" in result.output
    assert f"lists {gone.name}, which is missing" in result.output


def test_validate_reports_logs_without_a_manifest_and_missing_files(tmp_path: Path) -> None:
    (tmp_path / "logs").mkdir()
    (tmp_path / "logs" / "a.mcap").write_bytes(b"\x89MCAP0\r\n")
    result = runner.invoke(app, ["validate", str(tmp_path / "logs"), str(tmp_path / "none.mcap")])
    assert result.exit_code == 1
    assert f"no {MANIFEST_NAME}" in result.output
    assert "truncated" in result.output
    assert f"{tmp_path / 'none.mcap'}: file not found" in result.output


def test_convert_rejects_an_unknown_mode(converted_sample: ConvertedSample, tmp_path: Path) -> None:
    result = runner.invoke(
        app,
        [
            "convert",
            "--data-dir",
            str(converted_sample.data_dir),
            "--split",
            "val_seen",
            "--out",
            str(tmp_path),
            "--mode",
            "full",
        ],
    )
    assert result.exit_code != 0 and "--mode must be one of" in result.output


def test_validate_checks_a_run_directorys_logs_without_a_manifest(
    sample_dir: Path, tmp_path: Path
) -> None:
    from skyvln_eval.converters.validate import RUN_LOGS_DIR, RUN_REPORT_FILE
    from skyvln_eval.harness import RunConfig, make_executor, run
    from skyvln_eval.harness.run import REPORT_FILE
    from skyvln_eval.harness.runner import LOGS_DIR

    assert (RUN_LOGS_DIR, RUN_REPORT_FILE) == (LOGS_DIR, REPORT_FILE)  # the same layout
    config = RunConfig(system="validated", data=str(sample_dir), splits=("val_unseen",), limit=2)
    run_dir = tmp_path / "run"
    run(config, run_dir, executor=make_executor("serial", 1))
    for target in (run_dir, run_dir / "logs" / "val_unseen"):
        result = runner.invoke(app, ["validate", str(target)])
        assert result.exit_code == 0, result.output
        assert "2 MCAP file(s) (1 folder(s) of a run's logs)" in result.output
        assert result.output.rstrip().endswith("message(s) checked, ok")

    # The same logs elsewhere are not a run's: their manifest is missing, and the summary
    # counts that problem where it is (a folder), not in "0 file(s)".
    loose = tmp_path / "loose"
    (run_dir / "logs" / "val_unseen").rename(loose)
    one = sorted(loose.glob("*.mcap"))[0]
    one.write_bytes(one.read_bytes()[:-3])
    result = runner.invoke(app, ["validate", str(loose)])
    assert result.exit_code == 1
    assert f"{loose}: 2 MCAP file(s) but no {MANIFEST_NAME}" in result.output
    assert f"{one}: truncated" in result.output  # named once, not twice
    assert "2 problem(s): 1 in 1 file(s), 1 in 1 folder(s)" in result.output


def test_records_left_out_are_counted_once_and_kept_in_the_folder(
    dataset_factory: Callable[..., Path], tmp_path: Path, cli: Callable[..., CliOutcome]
) -> None:
    # Three problems in one record printed three 'skipped:' lines and '3 invalid record(s)'.
    bad = make_record(route_index="2_1", angle="north", lat_ratio=-1.0, pre_dialogs="x")
    root = dataset_factory({"val_seen": [make_record(route_index="1_1"), bad]})
    args = ["convert", "--data-dir", str(root), "--split", "val_seen", "--out", str(tmp_path)]
    result = cli(*args, "--skip-invalid")
    assert result.code == 0, result.err
    skipped = [line for line in result.err.splitlines() if line.startswith("skipped:")]
    assert len(skipped) == 1 and "record 1 (episode 1913__2_1)" in skipped[0]
    assert all(f in skipped[0] for f in ("'angle'", "'lat_ratio'", "'pre_dialogs'"))
    assert "1 converted" in result.out and "1 invalid record(s) left out" in result.out

    folder = tmp_path / "val_seen" / "andh"
    result = cli("validate", str(folder))
    assert result.code == 0, result.err  # left out on purpose: told, not a problem
    assert f"{folder}: left out at conversion: invalid record 1 (episode 1913__2_1)" in result.out
    assert f"ok; 1 left out at conversion ({LEFT_OUT_NAME})" in result.out

    (folder / LEFT_OUT_NAME).write_text("{")
    result = cli("validate", str(folder))
    assert result.code == 1 and f"{folder / LEFT_OUT_NAME}: cannot be read as JSON" in result.err


def test_an_episode_the_conversion_failed_is_a_problem_of_its_folder(
    dataset_factory: Callable[..., Path], tmp_path: Path, cli: Callable[..., CliOutcome]
) -> None:
    # Left out by choice (an invalid record) is told; failed to convert is a fault: the
    # folder is not the split asked for, and validate must not say ok.
    root = dataset_factory({"val_seen": [make_record(route_index="1_1")]})
    args = ["convert", "--data-dir", str(root), "--split", "val_seen", "--out", str(tmp_path)]
    assert cli(*args).code == 0
    folder = tmp_path / "val_seen" / "andh"
    failed = LeftOut("failed_episode", "1913__1_1", None, ("the map image does not decode",))
    write_left_out(folder / LEFT_OUT_NAME, "val_seen", "andh", [failed])
    result = cli("validate", str(folder))
    assert result.code == 1
    expected = "(episode 1913__1_1): its conversion failed: the map image does not decode"
    assert expected in result.out + result.err


def test_convert_names_an_out_that_is_a_file(
    tmp_path: Path, dataset_factory: Callable[..., Path]
) -> None:
    # An audit: "afile: File exists (EEXIST)", from the lock file made inside it.
    root = dataset_factory({"val_seen": [make_record()]})
    afile = tmp_path / "afile"
    afile.write_text("mine")
    result = runner.invoke(
        app, ["convert", "--data-dir", str(root), "--split", "val_seen", "--out", str(afile)]
    )
    # The CLI's entry point prints a ConfigError and exits 2; the runner hands it over.
    assert isinstance(result.exception, ConfigError), result.output
    assert f"output folder {afile} is an existing file, not a folder" in str(result.exception)
    assert afile.read_text() == "mine"

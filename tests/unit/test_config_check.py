"""`leadthrough config check CELL.toml` (gateway/config_check.py): every section read by its own
loader, every error at once with file, section and key; exit 78 (EX_CONFIG) on any."""

from __future__ import annotations

from pathlib import Path

from gateway.cli import main
from gateway.config_check import check_cell, problems

REPO = Path(__file__).resolve().parents[2]
SIM_CELL = REPO / "deploy" / "config" / "sim_cell.toml"


def _cell(tmp_path: Path, edit) -> Path:
    path = tmp_path / "cell.toml"
    path.write_text(edit(SIM_CELL.read_text()))
    return path


def test_the_shipped_configs_pass(capsys):
    for name in ("sim_cell.toml", "cell.toml"):
        assert main(["config", "check", str(REPO / "deploy" / "config" / name)]) == 0
    assert "[can] ok" in capsys.readouterr().out


def test_errors_in_two_sections_are_both_reported_with_section_and_key(tmp_path, capsys):
    path = _cell(
        tmp_path,
        lambda t: t.replace("[can]\n", "[can]\nlost_cycle_anser = 1\n", 1).replace(
            "enabling_confirm_polls = 2", "enabling_confirm_polls = 0", 1
        ),
    )
    result = check_cell(path)
    assert "lost_cycle_anser" in result["can"] and "[can]" in result["can"]
    assert "enabling_confirm_polls" in result["gateway"]
    assert result["modbus"] == "" and result["control"] == ""
    assert main(["config", "check", str(path)]) == 78
    err = capsys.readouterr().err
    assert "lost_cycle_anser" in err and "enabling_confirm_polls" in err and "2 error(s)" in err


def test_an_unknown_section_is_one_error_and_an_unreadable_file_is_one_too(tmp_path):
    path = _cell(tmp_path, lambda t: t + "\n[contorl]\nx = 1\n")
    errors = problems(path)
    assert len(errors) == 1 and "contorl" in errors[0]
    bad = tmp_path / "bad.toml"
    bad.write_text("[can\n")
    assert list(check_cell(bad)) == ["file"]
    assert main(["config", "check", str(tmp_path / "missing.toml")]) == 78


def test_the_json_schema_accepts_the_shipped_configs_and_refuses_a_typo(tmp_path):
    import tomllib

    import jsonschema

    from gateway.config_check import cell_schema

    validator = jsonschema.Draft202012Validator(cell_schema())
    jsonschema.Draft202012Validator.check_schema(cell_schema())
    for name in ("sim_cell.toml", "cell.toml"):
        doc = tomllib.loads((REPO / "deploy" / "config" / name).read_text())
        assert list(validator.iter_errors(doc)) == []
    typo = tomllib.loads(SIM_CELL.read_text().replace("[can]\n", "[can]\ndeadline_ss = 1\n", 1))
    errors = [e for e in validator.iter_errors(typo)]
    assert errors and "deadline_ss" in errors[0].message
    wrong = tomllib.loads(SIM_CELL.read_text().replace("[modbus]\n", "[modbus]\nport_x = 1\n", 1))
    assert list(validator.iter_errors(wrong))


def test_the_gateway_refuses_to_start_on_a_childs_bad_section_naming_it_once(tmp_path, caplog):
    import argparse
    import logging

    from gateway.supervisor import cli_main

    path = _cell(tmp_path, lambda t: t.replace("[can]\n", "[can]\ndeadline_ss = 1\n", 1))
    args = argparse.Namespace(config=path, bus=None, no_spawn=False)
    with caplog.at_level(logging.ERROR, logger="leadthrough.gateway"):
        assert cli_main(args) == 78  # before any zenoh session or child process
    refused = [r.getMessage() for r in caplog.records if "refused" in r.getMessage()]
    naming = [m for m in refused if "deadline_ss" in m]  # then one line: how many, and no start
    assert len(naming) == 1 and "[can]" in naming[0] and str(path) in naming[0], refused

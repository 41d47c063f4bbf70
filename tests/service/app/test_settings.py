"""Settings: defaults without configuration; file < environment < command line."""

from __future__ import annotations

from pathlib import Path

from flocklab.service.app import load_settings
from flocklab.service.serve import cli_main


def test_defaults_need_no_configuration(monkeypatch, tmp_path):
    monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path))
    monkeypatch.delenv("FLOCKLAB_SETTINGS_FILE", raising=False)
    s = load_settings()
    assert s.data_dir == tmp_path / "flocklab"
    assert s.api_key is None and s.cors_origins == [] and s.workers == 1
    cfg = s.supervisor_config()
    assert cfg.threads_per_worker >= 1 and cfg.limits.max_agents == s.max_agents


def test_file_then_environment_then_flags(monkeypatch, tmp_path):
    f = tmp_path / "flocklab.env"
    f.write_text("FLOCKLAB_WORKERS=3\nFLOCKLAB_MAX_QUEUED=7\nFLOCKLAB_API_KEY=from-file\n")
    monkeypatch.setenv("FLOCKLAB_MAX_QUEUED", "9")
    s = load_settings(f, workers=5)
    assert (s.workers, s.max_queued) == (5, 9)
    assert s.api_key is not None and s.api_key.get_secret_value() == "from-file"
    assert "from-file" not in repr(s)  # secrets stay out of logs
    monkeypatch.setenv("FLOCKLAB_SETTINGS_FILE", str(f))
    assert load_settings().workers == 3


def test_serve_refuses_a_missing_settings_file(capsys):
    assert cli_main(["--settings", str(Path("/nonexistent/flocklab.env"))]) == 2
    assert "settings file not found" in capsys.readouterr().err

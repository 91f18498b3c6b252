"""Thin entry points: ``inhand-exp`` (the Hydra app)."""

from __future__ import annotations

import sys
from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig

from inhand_exp.config import ConfigError, register_configs, validate
from inhand_exp.learn.ppo import CheckpointError
from inhand_exp.task.goals import GoalsError

CONF_DIR = Path(__file__).resolve().parents[2] / "conf"

register_configs()


def run(cfg: DictConfig, run_dir: Path, overrides: list[str]) -> Path:
    """Validate ``cfg``, open the run log in ``run_dir`` and do what ``cfg.mode`` asks."""
    from inhand_exp.record import RunLog
    from inhand_exp.runinfo import run_config_message

    validate(cfg)
    if cfg.learner.name != "ppo":
        raise ConfigError(f"learner={cfg.learner.name} is not built yet; use learner=ppo")
    for what, name in (("checkpoint", cfg.checkpoint), ("goal file", cfg.eval.goals_file)):
        if name and not Path(name).is_file():  # before anything is written
            raise FileNotFoundError(f"{what} {name} not found")
    log_path = run_dir / cfg.log.file
    with RunLog(log_path, chunk_size=cfg.log.chunk_size_bytes,
                flush_every_s=cfg.log.flush_every_s) as log:
        log.write("/run/config", run_config_message(cfg, run_dir, overrides))
        log.flush()
        from inhand_exp.experiment import run_job

        run_job(cfg, run_dir, log)
    return log_path


@hydra.main(version_base="1.3", config_path=str(CONF_DIR), config_name="config")
def _app(cfg: DictConfig) -> None:
    hc = HydraConfig.get()
    try:
        log_path = run(cfg, Path(hc.runtime.output_dir), list(hc.overrides.task))
    except (ConfigError, CheckpointError, GoalsError, FileNotFoundError) as err:
        print(f"inhand-exp: {err}", file=sys.stderr)
        raise SystemExit(2) from None
    print(f"run written to {log_path.parent}  (log: {log_path})")


def main() -> None:
    if not (CONF_DIR / "config.yaml").is_file():
        sys.exit(f"inhand-exp: config tree not found at {CONF_DIR}; "
                 "install from a source checkout with `pip install -e .`")
    _app()

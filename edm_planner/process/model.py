"""The EDM process model (the ``process:`` section of the machine YAML): moved to
:mod:`edm_planner.cnc.process_model` (issue 27), below the machine configuration that reads it; its names
are re-exported here, where the process layer has always had them.
"""

from ..cnc.process_model import DEFAULT_PROCESS, REQUIRED_REGIMES, ProcessModel, Regime, parse_process

__all__ = ["DEFAULT_PROCESS", "REQUIRED_REGIMES", "ProcessModel", "Regime", "parse_process"]

"""The testbed: experiment runner, lossless MCAP records, and the live monitor."""

from rwlab.testbed.load import load_record
from rwlab.testbed.record import RecordWriter, read_record
from rwlab.testbed.runner import ExperimentConfig, RunSummary, run_experiment

__all__ = [
    "ExperimentConfig",
    "RecordWriter",
    "RunSummary",
    "load_record",
    "read_record",
    "run_experiment",
]

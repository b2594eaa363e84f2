"""An executor for ``flows._pipeline.scene_pipeline`` that runs nothing and records the graph."""

from __future__ import annotations


class RecordingExecutor:
    """Each handle is the ``stage/label`` that made it; ``calls`` and ``configs`` hold each
    submission's inputs (as those handles) and config, so a test can check the wiring."""

    def __init__(self):
        self.calls, self.configs = {}, {}

    def submit(self, stage_name, config, inputs, label):
        handle = f"{stage_name}/{label}"
        self.calls[handle], self.configs[handle] = inputs, config
        return handle

    def result(self, handle):
        raise AssertionError("not run")

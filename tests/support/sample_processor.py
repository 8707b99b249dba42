"""A custom processor for the tests of `netapp serve --processor package.module:Class`: no model, a JSON output."""

from __future__ import annotations

import numpy as np

from netapp.sdk import Processor


class MeanColour(Processor):
    name = "mean-colour"

    def process(self, batch):
        return [{"mean_bgr": [round(float(v), 1) for v in np.asarray(image).mean(axis=(0, 1))]} for image in batch]


class NotAProcessor:
    pass

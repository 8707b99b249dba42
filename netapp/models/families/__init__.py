"""The families the model layer knows, in the order they are asked: each claims an export by its metadata when it
has any, else by its shapes, the most particular shapes first (an anchor count) and the loosest last (rows of 6,
DETR queries). Adding a family is one file in this folder and a line here."""

from __future__ import annotations

from netapp.models.card import ModelCard, ModelRefused
from netapp.models.families import dfine, end2end, rfdetr, rtdetr, ultralytics, yolov5, yolox
from netapp.models.families.base import Family, Signature
from netapp.results import COCO_KEYPOINTS, COCO_SKELETON

FAMILIES: tuple[Family, ...] = (
    ultralytics.FAMILY,
    yolox.FAMILY,
    yolov5.FAMILY,
    rfdetr.FAMILY,
    dfine.FAMILY,
    end2end.FAMILY,
    rtdetr.FAMILY,
)
BY_NAME = {f.name: f for f in FAMILIES}


def what_to_give(task: str | None, layout: str | None) -> str:
    """The advice after a model no family read, for the flags already given (pure): never to give them again."""
    if task and layout:
        return (
            f"this is not a {layout} {task} export; `netapp model inspect MODEL` shows its outputs, or re-export the "
            "model in one of these forms"
        )
    if layout:
        return "give --task, or another --layout, or re-export the model in one of these forms"
    if task:
        return f"give --layout (one of {', '.join(BY_NAME)}), or re-export the model in one of these forms"
    return "give --task and --layout, or re-export the model in one of these forms"


def recognise(sig: Signature, layout: str | None = None) -> tuple[Family, ModelCard]:
    """The family that reads this model and its card; ModelRefused (one line) when none does, or when it
    contradicts itself. `layout` names the one family to try (--layout)."""
    if layout is not None and layout not in BY_NAME:
        raise ModelRefused(f"--layout {layout} is not a family: give one of {', '.join(BY_NAME)}")
    for family in (BY_NAME[layout],) if layout else FAMILIES:
        found = family.recognise(sig)
        if found is not None:
            break
    else:
        task = f" for --task {sig.task}" if sig.task else ""
        tried = f"the {layout} layout" if layout else "no known family"
        raise ModelRefused(
            f"outputs {sig.seen()} for input {sig.input_hw[1]}x{sig.input_hw[0]} match {tried}{task} "
            f"(known: {'; '.join(f.shapes for f in ((BY_NAME[layout],) if layout else FAMILIES))}): "
            f"{what_to_give(sig.task, layout)}"
        )
    names = sig.names or (tuple(found.default_names) if found.default_names else None)
    if names is None:
        names = tuple(f"class_{i}" for i in range(found.num_classes))
    if len(names) != found.num_classes:
        raise ModelRefused(
            f"the model has {found.num_classes} classes but {len(names)} class names were given: "
            "give --labels with one name per class"
        )
    keypoint_names = skeleton = None
    if found.keypoints and found.keypoints[0] == len(COCO_KEYPOINTS):
        keypoint_names, skeleton = COCO_KEYPOINTS, COCO_SKELETON  # the default skeleton: COCO's 17 person keypoints
    card = ModelCard(
        family=family.name,
        task=found.task,
        pixels=found.pixels,
        classes=tuple(names),
        inputs=sig.inputs,
        outputs=sig.outputs,
        why=found.why,
        keypoints=found.keypoints,
        keypoint_names=keypoint_names,
        skeleton=skeleton,
        mask_channels=found.mask_channels,
        extras=found.extras,
    )
    return family, card

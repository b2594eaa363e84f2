"""Random but valid instances of every artifact class, built from their declared specs."""

from __future__ import annotations

import typing

import numpy as np

from schemas import Artifact

DIM_SIZES = {"T": 3, "H": 5, "W": 4, "h": 3, "w": 2, "N": 7, "K": 4, "V": 2, "L": 3, "S": 6, "J": 2}


def random_array(dtype: str, dims, rng: np.random.Generator) -> np.ndarray:
    shape = tuple(d if isinstance(d, int) else DIM_SIZES[d] for d in dims)
    dt = np.dtype(dtype)
    if dt == np.bool_:
        return rng.random(shape) > 0.5
    if dt.kind in "iu":
        return rng.integers(0, 100, size=shape).astype(dt)
    a = rng.normal(size=shape).astype(dt)
    if a.size:
        a.flat[0] = np.nan  # NaN must survive the round trip too
    return a


def make_artifact(cls: type[Artifact], rng: np.random.Generator) -> Artifact:
    values = {}
    specs = cls.array_specs()
    for name, info in cls.model_fields.items():
        if name in specs:
            values[name] = random_array(specs[name].dtype, specs[name].dims, rng)
            continue
        nested = cls.nested_fields().get(name)
        if nested:
            sub, is_list = nested
            values[name] = [make_artifact(sub, rng), make_artifact(sub, rng)] if is_list else make_artifact(sub, rng)
            continue
        ann = info.annotation
        if typing.get_origin(ann) is typing.Literal:
            choices = typing.get_args(ann)
            values[name] = choices[int(rng.integers(len(choices)))]
        elif ann is str:
            values[name] = f"{name}-{rng.integers(1000)}"
        elif ann is bool:
            values[name] = bool(rng.integers(0, 2))
        elif ann is int:
            values[name] = int(rng.integers(0, 50))
        elif ann is float:
            values[name] = float(rng.normal())
        elif typing.get_origin(ann) is dict:
            key_t, val_t = typing.get_args(ann)
            if val_t is float:
                values[name] = {"a_m": 0.1 + float(rng.random()), "b_deg": 1e-17}
            elif val_t is int:
                values[name] = {"static recording": int(rng.integers(0, 500))}
            elif typing.get_origin(val_t) is dict:
                values[name] = {"j": {"revolute": float(rng.normal()), "prismatic": 2.0}}
            elif typing.get_origin(val_t) is list and typing.get_args(val_t) == (int,):
                values[name] = {"static recording": [int(x) for x in rng.integers(0, 500, size=4)]}
            elif typing.get_origin(val_t) is list:
                values[name] = {"curve": [float(x) for x in rng.normal(size=3)]}
        elif typing.get_origin(ann) is list:
            values[name] = ["one", "two"]
        elif not info.is_required():
            continue
        else:
            raise NotImplementedError(f"no factory for {cls.__name__}.{name}: {ann}")
    return cls(**values)

"""Stage base class, option tables and the one registry.

A stage is a thin wrapper: it stores validated options, declares named inputs and outputs
(keys of the per-frame context dict), may declare when it is not needed, and calls pure
functions from fgcli.ops. Importing this module does not import torch.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

from fgcli.errors import UsageError


@dataclass(frozen=True)
class Option:
    name: str
    type: str  # "float" | "int" | "bool" | "choice" | "str"
    default: Any
    help: str
    range: tuple | None = None  # (min, max) for numbers
    choices: tuple | None = None  # for "choice"

    def parse(self, value, where: str = "") -> Any:
        """Validate (and convert from a string when given on the command line)."""
        loc = f"{where}: " if where else ""
        try:
            if self.type == "float":
                v = float(value)
            elif self.type == "int":
                if isinstance(value, float) and not value.is_integer():
                    raise ValueError
                v = int(value)
            elif self.type == "bool":
                if isinstance(value, str):
                    low = value.lower()
                    if low not in ("1", "0", "true", "false", "on", "off", "yes", "no"):
                        raise ValueError
                    v = low in ("1", "true", "on", "yes")
                else:
                    v = bool(value)
            elif self.type == "choice":
                v = str(value)
                if v not in self.choices:
                    raise UsageError(f"{loc}option '{self.name}' must be one of "
                                     f"{', '.join(self.choices)} (got '{v}')")
            else:
                v = str(value)
        except (TypeError, ValueError):
            raise UsageError(f"{loc}option '{self.name}' expects {self.type} (got {value!r})") from None
        if self.range is not None and self.type in ("float", "int"):
            lo, hi = self.range
            if (lo is not None and v < lo) or (hi is not None and v > hi):
                raise UsageError(f"{loc}option '{self.name}'={v} outside range [{lo}, {hi}]")
        return v

    def describe(self) -> str:
        extra = ""
        if self.choices:
            extra = f" one of {{{', '.join(self.choices)}}}"
        elif self.range:
            extra = f" in [{self.range[0]}, {self.range[1]}]"
        return f"{self.name} ({self.type}{extra}, default {self.default!r}): {self.help}"


class Stage:
    """Base class. Subclasses set name, help, inputs, outputs, options and implement run()."""

    name: ClassVar[str] = ""
    help: ClassVar[str] = ""
    inputs: ClassVar[tuple[str, ...]] = ()
    outputs: ClassVar[tuple[str, ...]] = ()
    options: ClassVar[tuple[Option, ...]] = ()
    optional_inputs: ClassVar[tuple[str, ...]] = ()
    # Recurrent state: how many earlier jobs (generated frames, in sequence order) must have
    # run through this stage for its state to be what an uninterrupted run has at a job.
    # 0: no state; None: every job since the start of the sequence. The runner replays
    # them (computed, not written) when a run starts mid-sequence (--chunk, --resume).
    history: ClassVar[int | None] = 0
    # True for stages that call compiled kernels (fgcli.kernels.op): the runner loads (or
    # compiles) the kernels only for pipelines that have one
    uses_kernels: ClassVar[bool] = False

    def __init__(self, where: str = "", **opts):
        table = {o.name: o for o in self.options}
        unknown = [k for k in opts if k not in table]
        if unknown:
            raise UsageError(f"{where}: unknown option '{unknown[0]}' for stage '{self.name}' "
                             f"(options: {', '.join(table) or 'none'})")
        self.opts = {o.name: o.default for o in self.options}
        for k, v in opts.items():
            self.opts[k] = table[k].parse(v, where)

    def __getattr__(self, item):
        opts = self.__dict__.get("opts", {})
        if item in opts:
            return opts[item]
        raise AttributeError(item)

    def configure(self, built: list, where: str) -> None:
        """Called once a mode's stages are built (built: every (spec, stage) of the mode,
        in order; where: this stage's file:line): a stage may set what depends on another
        stage's options here, or raise UsageError when they conflict."""

    def needed(self, ctx: dict, facts: dict) -> tuple[bool, str]:
        """Whether the stage must run on this frame; (False, reason) lets the runner skip it.
        A skipped stage's outputs come from skip(ctx)."""
        return True, ""

    def skip(self, ctx: dict) -> dict:
        """Outputs when the stage is not needed (must be exact, cheap)."""
        raise NotImplementedError(f"stage {self.name} cannot be skipped")

    def run(self, ctx: dict) -> dict:
        raise NotImplementedError

    def fuse(self, nxt: "Stage", ctx: dict, facts: dict) -> dict | None:
        """This stage and the next one of the pipeline (``nxt``) in one pass, where a fused
        kernel computes what the two would: the outputs of both (the runner then skips
        ``nxt`` and times the pair as ``this+next``). None (the default): one after the
        other. Asked only when this stage is needed; a stage that fuses must return None
        unless ``nxt`` would run and its result would be the same."""
        return None


REGISTRY: dict[str, type[Stage]] = {}


def register(cls: type[Stage]) -> type[Stage]:
    if not cls.name:
        raise ValueError("stage without a name")
    if cls.name in REGISTRY:
        raise ValueError(f"stage '{cls.name}' registered twice")
    REGISTRY[cls.name] = cls
    return cls


def get_stage(name: str, where: str = "") -> type[Stage]:
    load_all()
    if name not in REGISTRY:
        raise UsageError(f"{where}: unknown stage '{name}' (known: {', '.join(sorted(REGISTRY))})")
    return REGISTRY[name]


def load_all() -> dict[str, type[Stage]]:
    """Import every stage module so it registers itself."""
    import importlib
    import pkgutil

    import fgcli.stages as pkg

    for m in pkgutil.iter_modules(pkg.__path__):
        if m.name not in ("base",):
            importlib.import_module(f"fgcli.stages.{m.name}")
    return REGISTRY

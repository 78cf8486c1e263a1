"""catanc: compile semantic specs of sense-react task graphs into CPU schedules.

The pipeline (docs/development.md, "Layout"): load a spec (:func:`load_spec`),
build its planning problem (:func:`catanc.model.problem.build_problem`), plan it
(:func:`plan`: Stage I, then Stage II), emit.

``plan``, ``Plan`` and ``Replanner`` (re-planning as compute times drift)
load the solvers on first use, so commands that only read specs stay quick.
"""

from typing import TYPE_CHECKING, Any

from catanc.errors import CatancError, SpecError

if TYPE_CHECKING:
    from catanc.model.load import load_spec, parse_spec
    from catanc.planning.planner import plan
    from catanc.planning.replan import Replanner
    from catanc.planning.types import Plan
    from catanc.spec.language import Spec

__version__ = "0.1.0"

__all__ = [
    "CatancError",
    "Plan",
    "Replanner",
    "Spec",
    "SpecError",
    "__version__",
    "load_spec",
    "parse_spec",
    "plan",
]


def __getattr__(name: str) -> Any:
    # Everything loads on first use: `import catanc.client` in an app node must stay light.
    if name in ("load_spec", "parse_spec"):
        from catanc.model import load  # noqa: PLC0415

        return getattr(load, name)
    if name == "Spec":
        from catanc.spec.language import Spec  # noqa: PLC0415

        return Spec
    if name == "plan":
        from catanc.planning.planner import plan  # noqa: PLC0415 - the solvers load on first use

        return plan
    if name == "Plan":
        from catanc.planning.types import Plan  # noqa: PLC0415

        return Plan
    if name == "Replanner":
        from catanc.planning.replan import Replanner  # noqa: PLC0415

        return Replanner
    raise AttributeError(f"module 'catanc' has no attribute {name!r}")

"""catanc: compile semantic specs of sense-react task graphs into CPU schedules.

The pipeline (``../shared/docs/style.md``): load a spec (:func:`load_spec`),
build its planning problem (:func:`catanc.problem.build_problem`), solve, emit.
"""

from catanc.errors import CatancError, SpecError
from catanc.load import load_spec, parse_spec
from catanc.spec import Spec

__version__ = "0.1.0"

__all__ = ["CatancError", "Spec", "SpecError", "__version__", "load_spec", "parse_spec"]

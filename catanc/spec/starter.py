"""``catanc init``: a commented starter spec that validates and compiles as written.

The text is a jinja2 template in the top-level ``templates/`` folder (package
data, like the deployment templates): it is a YAML file a maintainer reads and
edits as YAML, comments aligned, and a test compiles it as a user would.  Only
the app's name and the file's name are filled in.
"""

from __future__ import annotations

import re
import shlex
from functools import cache
from typing import TYPE_CHECKING

import yaml

from catanc.errors import UsageError
from catanc.spec.language import APP_NAME_PATTERN

if TYPE_CHECKING:
    import jinja2

STARTER_TEMPLATE = "starter.yaml.j2"
DEFAULT_APP = "my_app"
COMMENT_COLUMN = 25
"""Column (0-based) where the comment of the ``app:`` line starts, as on the lines around it."""


def starter_spec(app: str = DEFAULT_APP, file: str | None = None) -> str:
    """The starter spec for ``app``, its "Next:" commands naming ``file`` (default ``<app>.yaml``)."""
    if not re.match(APP_NAME_PATTERN, app):
        raise UsageError(f"--app {app!r}: an app name is letters, digits, _, . and -, starting with a letter or _")
    value = app if yaml.safe_load(app) == app else f'"{app}"'  # quote names YAML reads otherwise (true, null, 1e3)
    used = len("app: ") + len(value)
    return _template().render(
        app=value,
        app_padding=" " * max(1, COMMENT_COLUMN - used),
        file=shlex.quote(file if file is not None else f"{app}.yaml"),
    )


@cache
def _template() -> jinja2.Template:
    import jinja2  # noqa: PLC0415 - only `catanc init` renders it; every other command imports this module

    environment = jinja2.Environment(
        loader=jinja2.PackageLoader("catanc.templates", ""),
        undefined=jinja2.StrictUndefined,
        keep_trailing_newline=True,
        autoescape=False,
    )
    return environment.get_template(STARTER_TEMPLATE)

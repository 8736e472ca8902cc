"""The toolkit's exceptions: one root, specific subclasses that build their own message.

Anything a user can cause (a bad file, a wrong option, a missing map) raises one of these,
never an ``assert``: callers can catch ``SkyvlnError`` and show the message as it is.
"""

from __future__ import annotations

import errno
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from skyvln_eval.llm.types import RefusedRequest


class SkyvlnError(Exception):
    """Root of every error the toolkit raises on purpose."""


def listed(names: Sequence[object], limit: int = 12) -> str:
    """``names`` quoted and joined for an error message, cut after ``limit`` with how many
    more there are (``'a', 'b' and 3 more``): a cut list that does not say so reads as all
    of them."""
    shown = ", ".join(repr(name) for name in names[:limit])
    more = len(names) - limit
    return f"{shown} and {more} more" if more > 0 else shown or "none"


@dataclass(frozen=True)
class ValidationIssue:
    """One problem found in an input file, located as precisely as we can.

    ``record_index`` is the 0-based position of the record in the file's JSON list and
    ``field`` a path such as ``gt_path_corners[3][1]``; either is ``None`` when the problem
    concerns the whole file or the whole record. ``line`` is the record's 1-based line in a
    file of one record per line (JSON Lines), where an editor finds it.
    """

    file: str
    message: str
    record_index: int | None = None
    episode_id: str | None = None
    field: str | None = None
    line: int | None = None

    @property
    def record_location(self) -> str:
        """The file, record and episode (what names the record, without the field)."""
        where = self.file
        if self.record_index is not None:
            where += f", record {self.record_index}"
        if self.line is not None:
            where += f" on line {self.line}"
        if self.episode_id is not None:
            where += f" (episode {self.episode_id})"
        return where

    def __str__(self) -> str:
        field = f", field '{self.field}'" if self.field else ""  # none, or the record itself
        return f"{self.record_location}{field}: {self.message}"


class DataError(SkyvlnError):
    """Input data is missing or malformed."""


class AvdnFileError(DataError):
    """A whole annotation file cannot be used (missing, not JSON, not a list)."""

    def __init__(self, file: str, message: str) -> None:
        self.issue = ValidationIssue(file=file, message=message)
        super().__init__(str(self.issue))


class AvdnValidationError(DataError):
    """One or more records of an annotation file are invalid.

    ``issues`` holds every problem found, so a caller can report them all at once; ``hint``
    says what to do about them where the error is met (default: :data:`LOAD_HINT`).
    """

    max_listed = 20
    #: Where records are loaded: the ways to leave the invalid ones out.
    LOAD_HINT = (
        "fix them, or leave them out: `--skip-invalid` with `skyvln-eval summary` or "
        "`convert`, `skip_invalid=True` with load_split"
    )

    def __init__(self, issues: Sequence[ValidationIssue], hint: str | None = None) -> None:
        self.issues = tuple(issues)
        lines = [str(issue) for issue in self.issues[: self.max_listed]]
        more = len(self.issues) - len(lines)
        if more > 0:
            lines.append(f"... and {more} more problem(s); `skyvln-eval validate` lists them all")
        # Counted as what they are: a record may have several problems, and a problem may
        # be a trajectory's (a missing round), not one record's.
        records = {(i.file, i.record_index) for i in self.issues if i.record_index is not None}
        whole = len(self.issues) - sum(i.record_index is not None for i in self.issues)
        counts = [f"{len(records)} invalid record(s)"] if records else []
        counts += [f"{whole} other problem(s)"] if whole else []
        super().__init__(
            f"{', '.join(counts)} ({hint or self.LOAD_HINT}):\n"
            + "\n".join("  " + x for x in lines)
        )


class MapImageError(DataError):
    """A map image, or a file of its world layers, is missing or cannot be decoded."""

    def __init__(self, path: str, message: str, episode_id: str | None = None) -> None:
        where = f" (episode {episode_id})" if episode_id else ""
        super().__init__(f"{path}{where}: {message}")
        self.path = path


class MapShapeError(MapImageError):
    """A map decodes, but its width-resized raster has a shape it cannot be used in: too
    large or small to make, or not that of its world layers. ``map_shape_px`` is the
    (height, width) the resized map has or would have: ``validate`` compares it with the
    records' bounds to tell a record's wrong geo-reference from a wrong image."""

    def __init__(self, path: str, message: str, map_shape_px: tuple[int, int]) -> None:
        super().__init__(path, message)
        self.map_shape_px = map_shape_px


class NoGroundTruthError(SkyvlnError):
    """Scoring was asked for episodes whose ground truth is withheld (real AVDN test_unseen)."""

    def __init__(self, split: str, episode_ids: Sequence[str]) -> None:
        shown = ", ".join(list(episode_ids)[:5])
        super().__init__(
            f"split '{split}' has no ground truth for {len(episode_ids)} episode(s) ({shown}...): "
            "the real AVDN release keeps only the start view in test_unseen and its test server "
            "is closed, so these episodes cannot be scored. Score val_seen / val_unseen, or use "
            "the synthetic sample, whose test_unseen keeps its full ground truth."
        )


class FormatVersionError(SkyvlnError):
    """A persisted file was written by an incompatible version of a format."""

    def __init__(self, path: str, found: object, expected: object, what_to_do: str) -> None:
        super().__init__(
            f"{path}: format version {found!r} is not supported (expected {expected!r}). "
            f"{what_to_do}"
        )


class ConfigError(SkyvlnError):
    """A configuration value or command-line option is invalid."""


class ForeignRowsError(ConfigError):
    """A run directory holds result rows another configuration made: never resumed nor
    scored as the run's, whatever is allowed."""


#: The context key (of a ``PydanticCustomError``) by which a validator that checks a
#: free-form mapping (a controller's settings) names the field inside it, as a dotted path
#: below the error's location: :func:`describe_validation_error` appends it.
FIELD_PATH_CONTEXT = "field_path"


def describe_validation_error(error: Any, model: Any = None) -> str:
    """A pydantic ``ValidationError`` (or some of its ``errors()``) as ``"field.path: message;
    ..."`` (for ConfigError texts).

    Our own validators' messages are complete sentences: pydantic's "Value error, " prefix
    is dropped from them. Given the validated ``model`` (class), a field it does not know
    gets the close names it does (``temperatur``: did you mean 'temperature'?).
    """
    import difflib

    parts = []
    for e in error.errors() if hasattr(error, "errors") else error:
        text = str(e["msg"]).removeprefix("Value error, ").rstrip(".")
        if e.get("type") == "extra_forbidden" and e["loc"]:
            known = _field_names_at(model, e["loc"][:-1])
            close = difflib.get_close_matches(str(e["loc"][-1]), known, n=3)
            if close:
                text += f" (did you mean {', '.join(repr(c) for c in close)}?)"
            elif known:
                text += f" (known: {', '.join(known)})"
        if e.get("type") == "string_type" and isinstance(e.get("input"), bool | int | float):
            text += f" ({_unquoted_yaml(e['input'])})"
        loc = [str(p) for p in e["loc"]]
        inside = (e.get("ctx") or {}).get(FIELD_PATH_CONTEXT)
        if inside:  # a validator of a free-form mapping named the key inside it
            loc.append(str(inside))
        parts.append(f"{'.'.join(loc) or '(top level)'}: {text}")
    return "; ".join(parts)  # a sentence's own full stop would read ".;"


def _unquoted_yaml(value: bool | int | float) -> str:
    """Why YAML gave a text field a boolean or a number, and the cure."""
    if isinstance(value, bool):
        read = f"unquoted yes / no / on / off / true / false as {str(value).lower()}"
    else:
        read = f"the unquoted text as the number {value!r}, an underscore in digits as a separator"
    return f"YAML reads {read}: put the text in quotes"


def _field_names_at(model: Any, loc: Sequence[Any]) -> list[str]:
    """The fields of the pydantic model found at ``loc`` inside ``model`` (through
    optional, list and mapping fields, whose indexes and keys ``loc`` holds), or none."""
    import typing

    from pydantic import BaseModel

    def models_in(annotation: Any) -> list[Any]:
        if isinstance(annotation, type) and issubclass(annotation, BaseModel):
            return [annotation]
        return [m for arg in typing.get_args(annotation) for m in models_in(arg)]

    current: list[Any] = [model] if model is not None else []
    for part in loc:
        fields = [m.model_fields[part] for m in current if part in m.model_fields]
        if fields:
            current = models_in(fields[0].annotation)
        elif not current:
            return []
        # else: an index or key into a list or mapping of the models in hand
    return list(current[0].model_fields) if current else []


class SettingsError(ConfigError):
    """A component's settings mapping (a controller's) holds an unknown or invalid field.

    ``field`` is its dotted path inside the mapping (``weights.input``; empty for the
    mapping as a whole) and ``problem`` what is wrong with it, so a config loader can name
    the field by its own path (``dynamics.controller_settings.weights.input``).
    """

    def __init__(self, message: str, field: str, problem: str) -> None:
        super().__init__(message)
        self.field = field
        self.problem = problem


class UnknownNameError(ConfigError):
    """A registry lookup failed; the message suggests close matches."""

    def __init__(self, kind: str, name: str, known: Sequence[str]) -> None:
        import difflib

        close = difflib.get_close_matches(name, list(known), n=3)
        hint = f" Did you mean {', '.join(repr(c) for c in close)}?" if close else ""
        super().__init__(f"unknown {kind} {name!r}.{hint} Known: {', '.join(sorted(known))}.")


class ResultRecordError(DataError):
    """A per-episode result row (or a predictions entry) is malformed.

    The message names the file, the row (0-based), the episode and the field, like the
    annotation validator does.
    """

    def __init__(self, issue: ValidationIssue) -> None:
        self.issue = issue
        super().__init__(str(issue))


class AlteredGroundTruthError(DataError):
    """Result rows hold another ground truth than their episodes' in the dataset."""


class IncompleteRunError(DataError):
    """A run does not cover every episode of its split (or covers unknown ones).

    ``outside`` names what the unexpected episodes are not part of; ``hint`` says what to do.
    """

    max_listed = 20

    def __init__(
        self,
        what: str,
        missing: Sequence[str],
        unexpected: Sequence[str] = (),
        hint: str = "",
        outside: str = "the split",
    ) -> None:
        self.missing = tuple(missing)
        self.unexpected = tuple(unexpected)
        parts = []
        if self.missing:
            shown = ", ".join(self.missing[: self.max_listed])
            more = len(self.missing) - min(len(self.missing), self.max_listed)
            parts.append(
                f"{len(self.missing)} missing episode(s): {shown}"
                + (f" ... and {more} more" if more else "")
            )
        if self.unexpected:
            shown = ", ".join(self.unexpected[: self.max_listed])
            parts.append(f"{len(self.unexpected)} episode(s) not in {outside}: {shown}")
        end = f". {hint}" if hint else ""
        super().__init__(f"{what} is incomplete: " + "; ".join(parts) + end)


class RunDirBusyError(SkyvlnError):
    """Another process is running in this run directory (it holds the directory's lock)."""

    def __init__(self, run_dir: str, holder: dict[str, Any]) -> None:
        self.run_dir = run_dir
        self.holder = holder
        pid = holder.get("pid")
        who = f"process {pid}" if pid else "another process"
        if holder.get("command"):
            who += f" ({holder['command']})"
        if holder.get("started"):
            who += f", running since {holder['started']}"
        if holder.get("host"):
            who += f" on {holder['host']}"
        super().__init__(
            f"run directory {run_dir} is in use by {who}; a second run there would run the "
            "same episodes again. Wait for it to finish (the same command then resumes "
            "anything left), or choose another output directory."
        )


class RunStoppedError(SkyvlnError):
    """A run stopped before its end (e.g. refused credentials: no later episode could
    succeed), so what needs all of its episodes (a reproduce plan's tables) is not made.
    The episodes already recorded are kept; the same command resumes."""


class ResultsWriteError(DataError):
    """An episode's result row could not be written (a full disk, a quota, an I/O error).

    The rows written before it are intact: running the same command again resumes.
    """

    def __init__(self, path: str, episode: str, rows_kept: int, error: OSError) -> None:
        self.path = path
        self.error = error
        super().__init__(
            f"cannot record episode {episode} in {path}: {describe_os_error(error)}. The "
            f"{rows_kept} row(s) recorded before it are intact; free some space and run the "
            "same command again: it runs only the episodes that have no row."
        )


def describe_os_error(error: OSError) -> str:
    """An ``OSError`` as one plain sentence: what failed, on which file, and the errno."""
    text = error.strerror or str(error)
    if error.errno is not None:
        text += f" ({errno.errorcode.get(error.errno, error.errno)})"
    if error.filename is not None:
        text = f"{error.filename}: {text}"
    if error.errno in STORAGE_FULL_ERRNOS:
        text += ": the disk (or the file size or quota allowed) is full"
    return text


#: errno values that say the storage is full: no later write can succeed either.
STORAGE_FULL_ERRNOS = frozenset({errno.ENOSPC, errno.EFBIG, errno.EDQUOT})


class MetricInputError(SkyvlnError):
    """A metric or statistic was asked for on input it has no defined value for.

    Examples: an average over zero episodes, a paired test on systems that did not run
    the same episodes, a non-finite value where a finite one is required.
    """


class UnsafePickleError(DataError):
    """A pickled predictions file asked for something other than plain data."""

    def __init__(self, path: str, name: str) -> None:
        super().__init__(
            f"{path}: refused to unpickle {name!r}: an official-format predictions file may "
            "hold only plain containers, numbers, strings and numpy arrays. Do not load this "
            "file with numpy.load(allow_pickle=True) either; ask its author for the JSON "
            "predictions format."
        )


class McapLogError(DataError):
    """An MCAP log cannot be used: not MCAP, truncated, corrupt, or not what it should hold.

    The message names the file and says what is wrong, so a user can tell a damaged copy
    (fetch or convert it again) from a file of another kind.
    """

    def __init__(self, path: str, message: str) -> None:
        self.path = path
        super().__init__(f"{path}: {message}")


class SolverBuildError(SkyvlnError):
    """A controller's solver functions had to be compiled (``compile: always``) and could not be."""


class ActionParseError(SkyvlnError):
    """An LLM module's output is unusable: not one valid action of the closed vocabulary,
    or not the JSON its module asked for (sub-goals, HSD, a question, detections)."""


class LLMError(SkyvlnError):
    """An LLM backend could not produce a completion.

    What the failed request still told, for its record: the tokens the server reported
    for it (``None``: none reported; ``cached_prompt_tokens`` the part of the prompt a
    provider's prompt cache served), and the requests of the same attempt it turned down
    for their form before this one (``refused``:
    :class:`~skyvln_eval.llm.types.RefusedRequest`), each an attempt of its own. The
    backend sets them where it knows them; they default to nothing known.
    """

    prompt_tokens: int | None = None
    completion_tokens: int | None = None
    cached_prompt_tokens: int | None = None
    refused: tuple[RefusedRequest, ...] = ()


class LLMTransientError(LLMError):
    """A fault worth retrying: rate limit (429), server error (5xx), timeout, broken response.

    ``retry_after_s`` is the server's Retry-After hint when it gave one.
    """

    def __init__(self, message: str, retry_after_s: float | None = None) -> None:
        super().__init__(message)
        self.retry_after_s = retry_after_s


class LLMEndpointError(LLMError):
    """The endpoint cannot serve the request at all (HTTP 404, 405, 410, 402 ...: no such
    route or model, payment required): not the model's answer, and sending the same
    request again would not help. Like a transient fault that used up its retries, it
    leaves the call unanswered: the episode measures the endpoint, not the model."""


class LLMContextOverflowError(LLMError):
    """The request is longer than the model's context window: sending it again is useless."""


class LLMAuthError(LLMError):
    """The server refused the credentials (HTTP 401 / 403): no later call can succeed.

    Not recorded as an episode's failure and carried on: it stops the run, naming the
    backend and the environment variable the key is read from (never the key).
    """


class LLMQuotaError(LLMAuthError):
    """The server refused the request for the account's quota or billing limit (OpenAI's
    HTTP 429 ``insufficient_quota``): no retry helps, so it stops the run as refused
    credentials do, naming the quota."""


class CacheMissError(SkyvlnError):
    """The ``replay`` backend was asked something its cache does not hold.

    Not an :class:`LLMError`: agents survive backend faults, but a replay that misses is
    no longer a replay, so it stops the run.
    """


class MissingExtraError(SkyvlnError):
    """An optional feature needs a package extra or model weights that are not installed."""

    def __init__(self, feature: str, extra: str, detail: str = "") -> None:
        more = f" ({detail})" if detail else ""
        super().__init__(
            f"{feature} needs the optional '{extra}' dependencies{more}: "
            f"pip install 'skyvln-eval[{extra}]'"
        )


class PerceptionError(SkyvlnError):
    """The world or camera cannot give what a perception component needs."""


def stops_the_run(error: BaseException) -> str | None:
    """Why ``error`` stops a whole run (no later episode could succeed), or ``None`` when it
    is the episode's own failure: refused credentials, a replay's cache miss, a full disk."""
    if isinstance(error, LLMAuthError | CacheMissError):
        return str(error)
    if isinstance(error, OSError) and error.errno in STORAGE_FULL_ERRNOS:
        return (
            f"cannot write the run's files: {describe_os_error(error)}; free some space and "
            "run the same command again"
        )
    return None

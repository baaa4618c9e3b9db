"""ROS 2 parameter files (``node: {ros__parameters: {...}}``) read without rclpy.

``read_ros_params`` merges the sections that apply to a node (``/**``, ``/**/controller``,
``controller``: rcl's wildcard rules, :func:`node_matches`) the way rcl does;
``check_ros_params`` also rejects what rcl's parser (rcl_yaml_param_parser) rejects although
PyYAML loads it: lists mixing types (``[1, 2.5]``: write ``[1.0, 2.5]``), lists of lists or of
mappings, lists holding null, and strings that YAML 1.1 reads as booleans inside string lists
(``[x, y]``: ``y`` is ``true``). A node handed such a file fails inside ``rclpy.init`` with a
parser message; this check names the offending parameter instead.

Every user file (parameter files, gains, spacecraft, campaign and robust specs) is read through
:func:`read_user_text` and :func:`safe_load`, so the same problem gets the same one line from
every command: a missing file, a symbolic-link loop, a directory, a file that is not UTF-8 text,
malformed YAML, and a mapping key given twice (PyYAML keeps the last one silently; a SIL once
flew the second gain under a header naming the first) are :class:`ConfigError`.

Before anything is read, the file must be a regular file (or a symbolic link to one): a FIFO, a
device or a socket is refused with one line, never opened in a way that blocks
(:func:`open_regular`; bags are read through it too). A user file larger than
:data:`USER_FILE_LIMIT` (1 MiB; a gains, spacecraft or spec file is a few kB) is refused before
it is read or parsed (PyYAML needs about 10 s and 250 MB per MB of YAML).
"""
from __future__ import annotations

import errno
import os
import re
import stat
from pathlib import Path

import yaml

from .errors import ConfigError


class UniqueKeyLoader(yaml.SafeLoader):
    """``yaml.SafeLoader`` that rejects a mapping key given twice, naming the key and both lines
    (merge keys ``<<`` may still be overridden, as YAML says)."""

    def construct_mapping(self, node, deep=False):
        """The mapping of ``node``; ConstructorError at the second occurrence of a key."""
        if isinstance(node, yaml.MappingNode):
            seen: dict = {}
            for key_node, _ in node.value:
                if key_node.tag == "tag:yaml.org,2002:merge":
                    continue
                key = self.construct_object(key_node, deep=True)
                try:
                    first = seen.setdefault(key, key_node.start_mark.line)
                except TypeError:  # an unhashable key: the base class reports it
                    continue
                if first != key_node.start_mark.line:
                    raise yaml.constructor.ConstructorError(
                        "while constructing a mapping", node.start_mark,
                        f"duplicate key {key!r} (first given at line {first + 1}; keep one)", key_node.start_mark)
        return super().construct_mapping(node, deep)


def safe_load(text: str):
    """``yaml.safe_load`` that rejects duplicate mapping keys (:class:`UniqueKeyLoader`)."""
    return yaml.load(text, Loader=UniqueKeyLoader)  # noqa: S506 - a SafeLoader subclass


_OS_REASONS = {
    errno.ENOENT: "file not found",
    errno.ELOOP: "symbolic link loop (too many levels of symbolic links); point it at a real file",
    errno.EISDIR: "is a directory; expected a file",
    errno.EACCES: "permission denied",
    errno.ENAMETOOLONG: "file name too long",
    errno.ENOTDIR: "a component of the path is not a directory",
}


def os_reason(exc: OSError) -> str:
    """The one wording every command uses for an OSError on a user's path."""
    return _OS_REASONS.get(exc.errno, exc.strerror or str(exc))


def check_path(path, option: str | None = None) -> None:
    """ConfigError if ``path`` cannot even be looked up (a symbolic link loop, a too-long name);
    a path that does not exist yet is fine (outputs), and other errors are left to the caller's
    own checks. ``option``: the command-line option named in the message (else the path)."""
    try:
        os.stat(path)
    except FileNotFoundError:
        return
    except OSError as exc:
        if exc.errno in (errno.ELOOP, errno.ENAMETOOLONG):  # the rest: the caller's own checks name the option
            raise ConfigError(option or path, None, (f"{path}: " if option else "") + os_reason(exc)) from None


#: Largest user file read [bytes]: 1 MiB. Every YAML or JSON input (gains, spacecraft, design and
#: campaign specs, scenario, parameter and robust-spec files, a bag's metadata.yaml) is checked
#: against it before it is read or parsed.
USER_FILE_LIMIT = 1 << 20

_KINDS = ((stat.S_ISFIFO, "a FIFO (named pipe)"), (stat.S_ISCHR, "a character device"),
          (stat.S_ISBLK, "a block device"), (stat.S_ISSOCK, "a socket"))


def _refuse_irregular(path, mode: int) -> None:
    """ConfigError unless ``mode`` is a regular file's: what the path is instead, and where a
    symbolic link points."""
    if stat.S_ISREG(mode):
        return
    if stat.S_ISDIR(mode):
        raise ConfigError(path, None, _OS_REASONS[errno.EISDIR])
    kind = next((name for test, name in _KINDS if test(mode)), "not a regular file")
    what = (f"is a symbolic link to {kind} ({os.path.realpath(path)})" if os.path.islink(path) else f"is {kind}")
    raise ConfigError(path, None, f"{what}, not a regular file; point it at a regular file")


def _size_text(n: int) -> str:
    return f"{n >> 20} MiB" if n >= 1 << 20 and n % (1 << 20) == 0 else f"{n} bytes"


def too_large(path, size: int, limit: int = USER_FILE_LIMIT) -> ConfigError:
    """The one line for a user file over the size limit (``size`` bytes or more).

    Parameters
    ----------
    path : str or Path
        The file.
    size : int
        Its size in bytes (at least what was seen).
    limit : int
        The limit in bytes.

    Returns
    -------
    ConfigError
        ``<path>: too large (N bytes): input files are limited to 1 MiB ...``.
    """
    return ConfigError(path, None, f"too large ({size} bytes): input files are limited to {_size_text(limit)} "
                                   "(a gains, spacecraft or spec file is a few kB); is it the right file?")


def open_regular(path):
    """Open ``path`` for reading (binary) if it is a regular file or a symbolic link to one.

    The file is looked at (``stat``) before it is opened, so a device is never opened, and opened
    without blocking (a FIFO would block ``open`` and ``read`` until a writer comes), then
    looked at again (``fstat``: a path swapped in between is caught).

    Parameters
    ----------
    path : str or Path
        The file.

    Returns
    -------
    io.BufferedReader
        The open file, blocking reads.

    Raises
    ------
    ConfigError
        A FIFO, a device, a socket or a directory (or a link to one), naming what it is.
    OSError
        The file cannot be looked up or opened (missing, permission): the caller words it.
    """
    _refuse_irregular(path, os.stat(path).st_mode)
    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
    try:
        _refuse_irregular(path, os.fstat(fd).st_mode)
        os.set_blocking(fd, True)
    except BaseException:
        os.close(fd)
        raise
    return os.fdopen(fd, "rb")


def is_regular_file(path) -> bool:
    """Whether a regular file (or a symbolic link to one) is at ``path``.

    Parameters
    ----------
    path : str or Path
        The path looked at (never opened).

    Returns
    -------
    bool
        True for a regular file, False when nothing is there (a dangling link included).

    Raises
    ------
    ConfigError
        Anything else is there (a FIFO, a device, a socket, a directory, a link to one, a link loop).
    """
    try:
        mode = os.stat(path).st_mode
    except (FileNotFoundError, NotADirectoryError):
        return False
    except OSError as exc:
        raise ConfigError(path, None, os_reason(exc)) from None
    _refuse_irregular(path, mode)
    return True


def read_regular(path, limit: int | None = USER_FILE_LIMIT) -> bytes:
    """The bytes of a regular file (:func:`open_regular`), refused over ``limit`` before reading.

    Parameters
    ----------
    path : str or Path
        The file.
    limit : int or None
        Largest size read [bytes] (None: no limit, e.g. a bag's MCAP file).

    Returns
    -------
    bytes
        The content.

    Raises
    ------
    ConfigError
        Not a regular file, or larger than ``limit`` (checked on its size, then on what is read).
    OSError
        Missing or unreadable (as raised).
    """
    with open_regular(path) as fh:
        size = os.fstat(fh.fileno()).st_size
        if limit is not None and size > limit:
            raise too_large(path, size, limit)
        data = fh.read() if limit is None else fh.read(limit + 1)
    if limit is not None and len(data) > limit:
        raise too_large(path, len(data), limit)
    return data


def _os_error(path, exc: OSError, expected: str) -> ConfigError:
    reason = os_reason(exc)
    return ConfigError(path, None, f"{reason} ({expected})" if expected and exc.errno == errno.ENOENT else reason)


def check_user_file(path, expected: str = "", limit: int = USER_FILE_LIMIT) -> None:
    """The checks of :func:`read_user_text` without reading (for a reader outside this module):
    there, a regular file, at most ``limit`` bytes.

    Parameters
    ----------
    path : str or Path
        The file.
    expected : str
        What the file should be, added to "file not found".
    limit : int
        Largest size [bytes].

    Raises
    ------
    ConfigError
        One line naming the file and the problem.
    """
    try:
        st = os.stat(path)
    except OSError as exc:
        raise _os_error(path, exc, expected) from None
    _refuse_irregular(path, st.st_mode)
    if st.st_size > limit:
        raise too_large(path, st.st_size, limit)


def read_user_text(path, expected: str = "") -> str:
    """The text of a user's file, UTF-8; ConfigError naming the file and the fix otherwise
    (missing, a link loop, not a regular file, over :data:`USER_FILE_LIMIT`, not UTF-8).

    ``expected``: what the file should be, appended to "file not found" (e.g. "expected a ROS 2
    parameter YAML file").
    """
    path = Path(path)
    try:
        data = read_regular(path)
    except OSError as exc:
        raise _os_error(path, exc, expected) from None
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        raise ConfigError(path, None, f"not UTF-8 text (byte 0x{data[exc.start]:02x} at line {line}, offset {exc.start}); "
                                      "save the file as UTF-8") from None


def yaml_error(path, exc: yaml.YAMLError) -> ConfigError:
    """The one line for malformed YAML (and duplicate keys): where and what."""
    mark = getattr(exc, "problem_mark", None)
    at = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
    return ConfigError(path, None, f"malformed YAML{at}: {getattr(exc, 'problem', None) or exc}")


def load_user_yaml(path, expected: str = ""):
    """A user's YAML file parsed (:func:`read_user_text`, :func:`safe_load`); ConfigError for any
    problem (missing, loop, not UTF-8, malformed, duplicate key)."""
    text = read_user_text(path, expected)
    try:
        return safe_load(text)
    except yaml.YAMLError as exc:
        raise yaml_error(path, exc) from None


def _load(path) -> dict:
    """The parsed file, checked to be ``{node: {ros__parameters: {...}}}`` (read once)."""
    path = Path(path)
    doc = load_user_yaml(path, "expected a ROS 2 parameter YAML file")
    if not isinstance(doc, dict) or not doc:
        raise ConfigError(path, None, "expected a mapping 'node_name: {ros__parameters: {...}}'")
    for name, body in doc.items():
        if not isinstance(body, dict) or not isinstance(body.get("ros__parameters"), dict):
            raise ConfigError(path, f"{name}.ros__parameters", "expected a mapping of parameters under 'ros__parameters'")
    return doc


def _section_regex(key: str) -> re.Pattern:
    """The node-name pattern of a section key, as rcl/rclpy match it against a node's fully
    qualified name: a key without a leading ``/`` is absolute (``controller`` == ``/controller``,
    the root namespace only), ``*`` matches within one name token and ``/**`` any number of
    namespace tokens, none included (``/**/controller`` matches ``/controller`` and
    ``/sat1/controller``; ``/**`` matches every node)."""
    key = "/" + str(key).lstrip("/")
    out = []
    for tok in key.split("/")[1:]:
        if tok == "**":
            out.append("(?:/[^/]+)*")
        else:
            out.append("/" + "[^/]*".join(re.escape(part) for part in tok.split("*")))
    return re.compile("".join(out) + "$")


def node_matches(key: str, node: str) -> bool:
    """Whether the parameter-file section ``key`` applies to the node ``node`` (a name such as
    ``controller``, taken as ``/controller``, or a fully qualified ``/sat1/controller``), with
    rcl's wildcard rules (checked against rclpy in tests/base/test_paramfile.py)."""
    return bool(_section_regex(key).match("/" + node.lstrip("/")))


def _merge(doc: dict, node: str | None) -> dict:
    """The ``ros__parameters`` of every section that applies to ``node`` (of every section if
    None), in file order, later ones winning, as rcl merges them."""
    merged: dict = {}
    for name, body in doc.items():
        if node is None or node_matches(name, node):
            merged.update(body["ros__parameters"])
    return merged


def read_ros_params(path, node: str | None = None) -> dict:
    """Merge the ``ros__parameters`` of the sections that apply to ``node`` (``/**``,
    ``/**/controller``, ``controller``, ... see :func:`node_matches`), or of every section if None."""
    return _merge(_load(path), node)


#: Plain scalars that rcl (YAML 1.1 core) reads as booleans.
YAML11_BOOLS = {s for w in ("y", "yes", "n", "no", "true", "false", "on", "off")
                for s in (w, w.upper(), w.capitalize())}


def _kind(v):
    if isinstance(v, bool):
        return "bool"
    if isinstance(v, int):
        return "integer"
    if isinstance(v, float):
        return "double"
    if isinstance(v, str):
        return "bool" if v in YAML11_BOOLS else "string"
    if v is None:
        return "null"
    return "nested"


def _walk(prefix, params, path):
    for key, v in params.items():
        name = f"{prefix}{key}"
        if isinstance(v, dict):
            _walk(name + ".", v, path)
        elif isinstance(v, (list, tuple)):
            kinds = {_kind(x) for x in v}
            if "nested" in kinds:
                raise ConfigError(path, name, "lists of lists or of mappings are not ROS 2 parameters; flatten "
                                              "them (e.g. a row-major list of numbers)")
            if "null" in kinds:
                raise ConfigError(path, name, "a ROS 2 parameter list cannot hold null")
            if len(kinds) > 1:
                raise ConfigError(path, name, f"ROS 2 parameter lists must hold one type, got {sorted(kinds)} "
                                              "(write 1.0 rather than 1 in a list of numbers; quote 'y'/'n')")


def load_ros_params(path) -> dict:
    """Read ``path`` once and validate every node's ``ros__parameters`` as rcl would.

    Returns
    -------
    dict
        the file's sections, ``{node key: {"ros__parameters": {...}}}``, for :func:`merge_ros_params`.
    """
    doc = _load(path)  # file, YAML and layout errors
    for body in doc.values():
        _walk("", body["ros__parameters"], path)
    return doc


def merge_ros_params(doc: dict, node: str | None = None) -> dict:
    """The parameters of the sections of ``doc`` (:func:`load_ros_params`) that apply to ``node``
    (every section if None), merged as rcl merges them."""
    return _merge(doc, node)


def check_ros_params(path, node: str | None = None) -> dict:
    """Validate every node's ``ros__parameters`` of ``path`` as rcl would; return the parameters
    :func:`read_ros_params` returns for ``node`` (one read of the file for both)."""
    return _merge(load_ros_params(path), node)

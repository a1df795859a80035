"""Helpers for the tests of a malformed file's error: change one field of a good file, and check that reading it
fails with one line naming the file and the field."""

import pytest
import yaml

from semmap.errors import ConfigError

#: as a value: remove the key
DROP = object()


def set_key(data, key, value):
    """Set ``key`` (dotted; list items by index, ``people.0.speed``) of a parsed YAML document to ``value``
    (:data:`DROP`: remove it)."""
    *parents, leaf = key.split(".")
    for p in parents:
        data = data[int(p)] if isinstance(data, list) else data[p]
    if value is DROP:
        del data[leaf]
    else:
        data[leaf] = value


def assert_one_line_error(read, path, message, data=None):
    """Write ``data`` (if given) to ``path`` as YAML; ``read(path)`` must raise one :class:`ConfigError` line
    that starts with the file's path and matches ``message``."""
    if data is not None:
        path.write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError, match=message) as err:
        read(path)
    assert str(err.value).startswith(f"{path}: ") and "\n" not in str(err.value)

"""ROS 2 message definitions from the installed interface files (no rclpy).

Finds ``<prefix>/share/<pkg>/msg/<Type>.msg`` through ``AMENT_PREFIX_PATH``, the running
Python's prefix, or relative to the installed Python package of the messages, and builds:

* the ``ros2msg`` schema text rosbag2 writes into MCAP files: the type's ``.msg`` text, then
  for each (recursive) dependency a line of 80 ``=``, ``MSG: <pkg>/<Type>`` and its text;
* the RIHS01 type description hash (from the ``.json`` file next to the ``.msg``);
* the ``offered_qos_profiles`` YAML text of a QoS list, as rosbag2 (Jazzy, metadata
  version 9) writes it.
"""

from __future__ import annotations

import importlib.util
import json
import os
import re
import sys
from dataclasses import dataclass
from pathlib import Path

PRIMITIVES = frozenset({
    'bool', 'byte', 'char', 'float32', 'float64', 'int8', 'uint8', 'int16', 'uint16',
    'int32', 'uint32', 'int64', 'uint64', 'string', 'wstring', 'time', 'duration'})
SEPARATOR = '=' * 80
#: rmw's "infinite" duration as rosbag2 writes it.
INFINITE = {'sec': 9223372036, 'nsec': 854775807}


class MessageDefinitionError(LookupError):
    """A message type's definition file cannot be found or read."""


def share_dirs(package: str) -> list[Path]:
    """Candidate ``share/<package>`` directories, most specific first."""
    prefixes = [p for p in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep) if p]
    prefixes.append(sys.prefix)
    dirs = [Path(p) / 'share' / package for p in prefixes]
    try:
        spec = importlib.util.find_spec(package)
    except (ImportError, ValueError):
        spec = None
    if spec is not None and spec.submodule_search_locations:
        pkg_dir = Path(next(iter(spec.submodule_search_locations)))
        # <prefix>/lib/pythonX.Y/site-packages/<pkg> -> <prefix>/share/<pkg>
        dirs.append(pkg_dir.parents[2] / 'share' / package)
        dirs.append(pkg_dir.parents[3] / 'share' / package)
    return dirs


def _split(type_name: str) -> tuple[str, str]:
    """``'sensor_msgs/msg/JointState'`` or ``'sensor_msgs/JointState'`` -> (pkg, Type)."""
    parts = type_name.split('/')
    if len(parts) == 3 and parts[1] == 'msg':
        return parts[0], parts[2]
    if len(parts) == 2:
        return parts[0], parts[1]
    raise MessageDefinitionError(
        f'type name {type_name!r} is not of the form <pkg>/msg/<Type>')


def definition_file(type_name: str, suffix: str = '.msg') -> Path:
    """The installed ``<Type>.msg`` (or ``suffix``) file of ``type_name``."""
    pkg, name = _split(type_name)
    tried = []
    for d in share_dirs(pkg):
        path = d / 'msg' / f'{name}{suffix}'
        if path.is_file():
            return path
        tried.append(str(path))
    raise MessageDefinitionError(
        f'no {suffix} file for {type_name!r}; looked in: ' + ', '.join(tried))


_FIELD = re.compile(r'^\s*([A-Za-z][\w/]*)')


def dependencies(package: str, text: str) -> list[str]:
    """Non-primitive field types of a ``.msg`` text, as ``pkg/Type``, in order."""
    deps: list[str] = []
    for line in text.splitlines():
        line = line.split('#', 1)[0].strip()
        if not line:
            continue
        m = _FIELD.match(line)
        if not m:
            continue
        base = re.split(r'[\[<]', m.group(1))[0]
        if base in PRIMITIVES or ('=' in line and base in PRIMITIVES):
            continue
        if base == 'Header':
            dep = 'std_msgs/Header'
        elif '/' in base:
            dep = base.replace('/msg/', '/')
        else:
            dep = f'{package}/{base}'
        if dep not in deps:
            deps.append(dep)
    return deps


def schema_text(type_name: str) -> str:
    """The ``ros2msg`` schema of ``type_name`` as rosbag2 stores it in MCAP."""
    pkg, _ = _split(type_name)
    return expanded_schema(pkg, definition_file(type_name).read_text())


def expanded_schema(pkg: str, main: str) -> str:
    """``main`` (a definition of package ``pkg``: a .msg text, or one half of a .srv)
    followed by a block per definition it uses, each once, as ``ros2msg`` schemas hold
    them (a line of ``=``, ``MSG: <pkg>/<Type>``, its text)."""
    blocks: list[str] = []
    seen: set[str] = set()
    queue = dependencies(pkg, main)
    while queue:
        dep = queue.pop(0)
        if dep in seen:
            continue
        seen.add(dep)
        text = definition_file(dep).read_text()
        blocks.append(f'{SEPARATOR}\nMSG: {dep}\n{text}')
        queue.extend(d for d in dependencies(dep.split('/')[0], text) if d not in seen)
    return '\n'.join([main.rstrip('\n')] + [b.rstrip('\n') for b in blocks]) + '\n'


def type_hash(type_name: str) -> str:
    """The RIHS01 type description hash of ``type_name`` ('' if not installed)."""
    try:
        data = json.loads(definition_file(type_name, '.json').read_text())
    except (MessageDefinitionError, OSError, ValueError):
        return ''
    pkg, name = _split(type_name)
    full = f'{pkg}/msg/{name}'
    for entry in data.get('type_hashes', []):
        if entry.get('type_name') == full:
            return str(entry.get('hash_string', ''))
    return ''


@dataclass(frozen=True)
class QosProfile:
    """The parts of a QoS profile rosbag2 records (policy names as rosbag2 v9 writes them).

    Durations are (sec, nsec); ``None`` means infinite.
    """

    history: str = 'keep_last'         # keep_last | keep_all | system_default | unknown
    depth: int = 10
    reliability: str = 'reliable'      # reliable | best_effort | system_default | ...
    durability: str = 'volatile'       # volatile | transient_local | ...
    liveliness: str = 'automatic'      # automatic | manual_by_topic | ...
    deadline: tuple[int, int] | None = None
    lifespan: tuple[int, int] | None = None
    liveliness_lease_duration: tuple[int, int] | None = None
    avoid_ros_namespace_conventions: bool = False


def _duration(d: tuple[int, int] | None) -> dict[str, int]:
    return dict(INFINITE) if d is None else {'sec': int(d[0]), 'nsec': int(d[1])}


def qos_dicts(profiles: list[QosProfile]) -> list[dict]:
    """QoS profiles as the dictionaries of rosbag2 metadata version 9."""
    return [{'history': p.history, 'depth': p.depth, 'reliability': p.reliability,
             'durability': p.durability, 'deadline': _duration(p.deadline),
             'lifespan': _duration(p.lifespan), 'liveliness': p.liveliness,
             'liveliness_lease_duration': _duration(p.liveliness_lease_duration),
             'avoid_ros_namespace_conventions': p.avoid_ros_namespace_conventions}
            for p in profiles]


def qos_yaml(profiles: list[QosProfile]) -> str:
    """``offered_qos_profiles`` text for MCAP channel metadata ('' for no profiles)."""
    import yaml

    dicts = qos_dicts(profiles)
    return yaml.safe_dump(dicts, sort_keys=False).strip() if dicts else ''

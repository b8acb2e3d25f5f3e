#!/usr/bin/env python3
"""Build the ROS 2 Jazzy interface packages control_msgs and tf2_msgs into this venv.

No PyPI wheel ships them, so ``./run.sh setup`` builds them here from the message
definitions in ``interfaces/<package>/`` (byte-for-byte copies of the Jazzy release
files, see ``interfaces/README.md``) with the pinned rosidl generators of the venv:

1. ``rosidl_adapter`` translates .msg/.srv/.action to .idl,
   ``rosidl_generator_type_description`` writes the type descriptions and RIHS01 hashes;
2. ``rosidl_generator_c``, ``rosidl_generator_py`` and the C type supports
   (``rosidl_typesupport_c``, ``_fastrtps_c``, ``_introspection_c``) generate sources;
3. the system C/C++ compiler builds the same libraries ``rosidl_generate_interfaces``
   builds for rclpy (``lib<pkg>__rosidl_{generator_c,typesupport_c,typesupport_fastrtps_c,
   typesupport_introspection_c,generator_py}.so`` and the Python extension modules);
4. the result is installed like the ROS wheels in the venv: Python package in
   site-packages, libraries in ``<venv>/lib`` (on LD_LIBRARY_PATH through the
   ros-wheels-bootstrapper), definitions/type descriptions in ``<venv>/share/<pkg>``,
   headers in ``<venv>/include/<pkg>`` and the ament index entries.

The C++ type supports are not built: rclpy and rmw_fastrtps_cpp only need the C ones.

A package that is already importable and was not built by this script (a sourced real
ROS 2 install, or a future wheel) is left alone: nothing is built and nothing shadows
it. A package built by this script is rebuilt only when its inputs changed (stamp file
``<venv>/share/<pkg>/arm_sim_interfaces.stamp``); every installed file is listed in
``<venv>/share/<pkg>/arm_sim_interfaces.files`` and removed before a rebuild.

Usage: ``<venv>/bin/python interfaces/build_interfaces.py [--force] [--jobs N] [pkg ...]``
"""

from __future__ import annotations

import argparse
import concurrent.futures
import hashlib
import importlib
import importlib.metadata
import importlib.util
import json
import logging
import os
import pathlib
import shutil
import subprocess
import sys
import sysconfig
import tempfile
import time

HERE = pathlib.Path(__file__).resolve().parent
# interfaces/<pkg>/ holds the definitions, not Python packages: keep the script's folder
# off sys.path so that `import control_msgs` does not find it as a namespace package.
sys.path[:] = [p for p in sys.path if pathlib.Path(p or '.').resolve() != HERE]
PACKAGES = ('control_msgs', 'tf2_msgs')
STAMP = 'arm_sim_interfaces.stamp'
MANIFEST = 'arm_sim_interfaces.files'
# generator name -> (module, GenerateCommandExtension class) of the rosidl wheels
GENERATORS = {
    'c': ('rosidl_generator_c.cli', 'GenerateC'),
    'py': ('rosidl_generator_py.cli', 'GeneratePython'),
    'typesupport_c': ('rosidl_typesupport_c.cli', 'GenerateCTypesupport'),
    'typesupport_fastrtps_c': ('rosidl_typesupport_fastrtps_c.cli',
                               'GenerateFastRTPSCTypesupport'),
    'typesupport_introspection_c': ('rosidl_typesupport_introspection_c.cli',
                                    'GenerateIntrospectionCTypesupport'),
}
PY_TYPESUPPORTS = ('rosidl_typesupport_c', 'rosidl_typesupport_fastrtps_c',
                   'rosidl_typesupport_introspection_c')


def log(msg: str) -> None:
    print(f'[interfaces] {msg}', flush=True)


def interface_files(src: pathlib.Path) -> list[pathlib.Path]:
    return sorted(p for d in ('msg', 'srv', 'action') if (src / d).is_dir()
                  for p in (src / d).iterdir() if p.suffix in ('.msg', '.srv', '.action'))


def inputs_digest(pkg: str) -> str:
    h = hashlib.sha256()
    h.update(pathlib.Path(__file__).read_bytes())
    src = HERE / pkg
    for p in [src / 'package.xml', *interface_files(src)]:
        h.update(str(p.relative_to(src)).encode() + b'\0' + p.read_bytes() + b'\0')
    # the generators, runtime libraries and dependency packages: every ROS wheel
    ros = sorted({f'{d.metadata["Name"]}=={d.version}' for d in importlib.metadata.distributions()
                  if (d.metadata['Name'] or '').lower().startswith(('ros-', 'rosidl', 'rclpy'))})
    h.update('\n'.join(ros).encode())
    h.update(sys.version.encode())
    return h.hexdigest()


def package_deps(pkg: str) -> list[str]:
    """The <depend>/<build_depend> interface packages of package.xml."""
    import xml.etree.ElementTree as ET
    root = ET.parse(HERE / pkg / 'package.xml').getroot()
    return [e.text.strip() for e in root if e.tag in ('depend', 'build_depend') and e.text]


# --------------------------------------------------------------------------- generate

def quiet() -> None:
    """Silence the generators' per-file chatter and rosidl_cli's warnings about the
    duplicate entry points the wheels register (egg-info and dist-info of one package)."""
    logging.disable(logging.WARNING)
    sys.stdout = open(os.devnull, 'w')  # for the worker's lifetime


def _type_description_tuples(idl_files: list[str], td_files: list[str]) -> list[str]:
    by_key = {(pathlib.Path(f).parent.name, pathlib.Path(f).stem): f for f in td_files}
    tuples = []
    for idl in idl_files:
        rel = idl.split(':', 1)[1] if ':' in idl else idl
        key = (pathlib.Path(rel).parent.name, pathlib.Path(rel).stem)
        if key not in by_key:
            raise ValueError(f'Type description file not found for {idl}')
        tuples.append(f'{rel}:{by_key[key]}')
    return tuples


def _run_generator(args: tuple) -> list[str]:
    """Run one rosidl generator extension (in a worker process)."""
    name, pkg, idl_files, include_paths, out, td_files = args
    module, cls = GENERATORS[name]
    ext = getattr(importlib.import_module(module), cls)
    quiet()
    kwargs = {'type_description_files': td_files} if name == 'c' else {}
    if name == 'c':
        # rosidl_cli 4.6.6 pairs .idl and .json files by file stem only, so
        # msg/GripperCommand.idl would get action/GripperCommand.json (wrong description
        # and hash in the C code). Pair them by <subfolder>/<stem>, as CMake does.
        import rosidl_generator_c.cli as c_cli
        c_cli.build_type_description_tuples = _type_description_tuples
    if name == 'py':
        instance = ext(name, typesupport_implementations=list(PY_TYPESUPPORTS))
    elif name == 'typesupport_c':
        instance = ext(name, typesupport_implementations=list(PY_TYPESUPPORTS[1:]))
    else:
        instance = ext(name)
    files = instance.generate(pkg, idl_files, include_paths, output_path=pathlib.Path(out),
                              **kwargs)
    return [str(f) for f in files or []]


def generate(pkg: str, prefix: pathlib.Path, build: pathlib.Path, jobs: int) -> dict:
    from rosidl_cli.command.hash.api import generate_type_hashes
    from rosidl_cli.command.translate.api import translate

    src = HERE / pkg
    share = prefix / 'share'
    # Dependencies' definitions: every installed interface package but this one (the
    # generators take the package name from the folder, share/<dep>/msg/X.idl).
    include_paths = sorted(str(p) for p in share.iterdir() if p.name != pkg and any(
        (p / d).is_dir() for d in ('msg', 'srv', 'action')))
    missing = [d for d in package_deps(pkg) if not (share / d).is_dir()]
    if missing:
        raise SystemExit(f'[interfaces] {pkg}: missing dependencies in {share}: {missing}')
    files = [f'{src}:{p.relative_to(src)}' for p in interface_files(src)]
    idl_root = build / 'idl' / pkg
    td_root = build / 'type_description' / pkg
    stdout, sys.stdout = sys.stdout, open(os.devnull, 'w')
    try:
        idl_files = [str(p) for p in translate(  # '<idl_root>:msg/X.idl'
            package_name=pkg, interface_files=files, include_paths=include_paths,
            output_format='idl', output_path=idl_root)]
        td_files = [str(p) for p in generate_type_hashes(
            package_name=pkg, interface_files=idl_files, include_paths=include_paths,
            output_path=td_root)]
    finally:
        sys.stdout.close()
        sys.stdout = stdout
    names = ('py', 'c', 'typesupport_fastrtps_c', 'typesupport_c',
             'typesupport_introspection_c')
    work = [(n, pkg, idl_files, include_paths, str(build / n / pkg), td_files) for n in names]
    with concurrent.futures.ProcessPoolExecutor(max_workers=min(jobs, len(work))) as pool:
        generated = dict(zip(names, pool.map(_run_generator, work)))
    return {'idl_root': idl_root, 'td_root': td_root, 'generated': generated}


# --------------------------------------------------------------------------- compile

def _compile(args: tuple[list[str], str]) -> str:
    cmd, obj = args
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        raise RuntimeError(f'compile failed: {" ".join(cmd)}\n{r.stdout}{r.stderr}')
    return obj


def compile_and_link(pkg: str, prefix: pathlib.Path, build: pathlib.Path, jobs: int
                     ) -> dict[str, pathlib.Path]:
    cc = os.environ.get('CC', 'cc')
    cxx = os.environ.get('CXX', 'c++')
    libdir = prefix / 'lib'
    # Every interface package our types reference, directly or not (the type descriptions
    # list all referenced types), as the libraries to link: what CMake's exported targets
    # would bring in.
    referenced = set()
    for f in (build / 'type_description' / pkg).rglob('*.json'):
        desc = json.loads(f.read_text())['type_description_msg']
        for t in desc['referenced_type_descriptions']:
            referenced.add(t['type_name'].split('/')[0])
    referenced.update(package_deps(pkg))
    if (HERE / pkg / 'action').is_dir():  # rosidl_generate_interfaces adds it for actions
        referenced.add('action_msgs')
    referenced.discard(pkg)
    link_pkgs = sorted(p for p in referenced
                       if (libdir / f'lib{p}__rosidl_generator_c.so').exists())
    if referenced - set(link_pkgs):
        raise SystemExit(f'[interfaces] {pkg}: no libraries in {libdir} for '
                         f'{sorted(referenced - set(link_pkgs))}')
    includes = [f'-I{build / g}' for g in (
        'c', 'py', 'typesupport_c', 'typesupport_fastrtps_c', 'typesupport_introspection_c')]
    # the wheels' headers: include/<pkg>/<pkg>/... per package, fastcdr in include/fastcdr
    includes += [f'-I{d}' for d in sorted((prefix / 'include').iterdir()) if d.is_dir()]
    includes.append(f'-I{prefix / "include"}')
    py_inc = [f'-I{sysconfig.get_paths()["include"]}']
    import numpy
    py_inc.append(f'-I{numpy.get_include()}')
    base = ['-fPIC', '-O2', '-w', '-DNDEBUG']
    cflags = base + ['-std=gnu11'] + includes
    cxxflags = base + ['-std=c++17'] + includes
    objdir = build / 'obj' / pkg

    def glob(gen: str, pattern: str) -> list[pathlib.Path]:
        return sorted((build / gen / pkg).glob(pattern))

    # (library, sources, extra compile flags)
    targets = {
        'rosidl_generator_c': (
            glob('c', '*/detail/*.c'), [f'-DROSIDL_GENERATOR_C_BUILDING_DLL_{pkg}']),
        'rosidl_typesupport_introspection_c': (
            glob('typesupport_introspection_c', '*/detail/*.c'),
            [f'-DROSIDL_TYPESUPPORT_INTROSPECTION_C_BUILDING_DLL_{pkg}']),
        'rosidl_typesupport_fastrtps_c': (
            glob('typesupport_fastrtps_c', '*/detail/*.cpp'),
            [f'-DROSIDL_TYPESUPPORT_FASTRTPS_C_BUILDING_DLL_{pkg}']),
        'rosidl_typesupport_c': (
            glob('typesupport_c', '*/*.cpp'), [f'-DROSIDL_TYPESUPPORT_C_BUILDING_DLL_{pkg}']),
        'rosidl_generator_py': (glob('py', '*/_*_s.c'), py_inc),
    }
    ext_srcs = {ts: build / 'py' / pkg / f'_{pkg}_s.ep.{ts}.c' for ts in PY_TYPESUPPORTS}

    jobs_list = []
    objects: dict[str, list[str]] = {}
    for lib, (srcs, flags) in [*targets.items(),
                               *[(f'ext_{ts}', ([s], py_inc)) for ts, s in ext_srcs.items()]]:
        if not srcs:
            raise SystemExit(f'[interfaces] {pkg}: no sources generated for {lib}')
        objects[lib] = []
        for s in srcs:
            obj = objdir / lib / (str(s.relative_to(build)).replace('/', '__') + '.o')
            obj.parent.mkdir(parents=True, exist_ok=True)
            compiler = [cxx] + cxxflags if s.suffix == '.cpp' else [cc] + cflags
            jobs_list.append((compiler + flags + ['-c', str(s), '-o', str(obj)], str(obj)))
            objects[lib].append(str(obj))
    t = time.monotonic()
    with concurrent.futures.ThreadPoolExecutor(max_workers=jobs) as pool:
        for _ in pool.map(_compile, jobs_list):
            pass
    log(f'{pkg}: compiled {len(jobs_list)} sources in {time.monotonic() - t:.0f} s')

    out = build / 'lib' / pkg
    out.mkdir(parents=True, exist_ok=True)

    def dep_libs(kind: str) -> list[str]:
        return [f'-l{p}__{kind}' for p in link_pkgs
                if (libdir / f'lib{p}__{kind}.so').exists()]

    link_common = [f'-L{out}', f'-L{libdir}', '-Wl,-rpath,$ORIGIN', '-Wl,--no-undefined']
    own = f'-l{pkg}__rosidl_generator_c'
    libs = {
        'rosidl_generator_c': dep_libs('rosidl_generator_c') + ['-lrosidl_runtime_c',
                                                                '-lrcutils'],
        'rosidl_typesupport_introspection_c': [own] + dep_libs(
            'rosidl_typesupport_introspection_c') + dep_libs('rosidl_generator_c') + [
            '-lrosidl_typesupport_introspection_c', '-lrosidl_runtime_c', '-lrcutils'],
        'rosidl_typesupport_fastrtps_c': [own] + dep_libs(
            'rosidl_typesupport_fastrtps_c') + dep_libs('rosidl_generator_c') + [
            '-lrosidl_typesupport_fastrtps_cpp', '-lrosidl_typesupport_fastrtps_c', '-lrmw',
            '-lrosidl_dynamic_typesupport', '-lfastcdr', '-lrosidl_runtime_c', '-lrcutils'],
        'rosidl_typesupport_c': [own] + dep_libs('rosidl_typesupport_c') + dep_libs(
            'rosidl_generator_c') + [
            '-lrosidl_typesupport_c', '-lrosidl_runtime_c', '-lrcutils'],
        'rosidl_generator_py': [f'-l{pkg}__rosidl_typesupport_c', own] + dep_libs(
            'rosidl_generator_py') + dep_libs('rosidl_typesupport_c') + dep_libs(
            'rosidl_generator_c') + ['-lrosidl_runtime_c', '-lrcutils'],
    }
    built: dict[str, pathlib.Path] = {}
    for lib, extra_libs in libs.items():
        target = out / f'lib{pkg}__{lib}.so'
        linker = cxx if lib in ('rosidl_typesupport_fastrtps_c', 'rosidl_typesupport_c') else cc
        # Python symbols stay undefined in the py library: the interpreter provides them.
        flags = [f for f in link_common if lib != 'rosidl_generator_py'
                 or f != '-Wl,--no-undefined']
        _compile(([linker, '-shared', '-o', str(target), *objects[lib], *flags,
                   f'-Wl,-soname,{target.name}', *extra_libs], str(target)))
        built[target.name] = target
    ext_suffix = sysconfig.get_config_var('EXT_SUFFIX')
    for ts in PY_TYPESUPPORTS:
        target = out / f'{pkg}_s__{ts}{ext_suffix}'
        _compile(([cc, '-shared', '-o', str(target), *objects[f'ext_{ts}'], f'-L{out}',
                   f'-L{libdir}', '-Wl,-rpath,$ORIGIN/../../..',
                   f'-l{pkg}__rosidl_generator_py', f'-l{pkg}__{ts}', own,
                   *dep_libs('rosidl_generator_c'), '-lrosidl_runtime_c', '-lrcutils'],
                  str(target)))
        built[target.name] = target
    return built


# --------------------------------------------------------------------------- install

def site_packages(prefix: pathlib.Path) -> pathlib.Path:
    return pathlib.Path(sysconfig.get_path('purelib', vars={'base': str(prefix)}))


def uninstall(pkg: str, prefix: pathlib.Path) -> None:
    """Remove what a previous build of ours installed (listed in its manifest)."""
    manifest = prefix / 'share' / pkg / MANIFEST
    if not manifest.exists():
        return
    paths = [prefix / line for line in manifest.read_text().splitlines() if line]
    (prefix / 'share' / pkg / STAMP).unlink(missing_ok=True)
    for p in paths:
        if p.is_file() or p.is_symlink():
            p.unlink()
    manifest.unlink(missing_ok=True)
    for d in sorted({p.parent for p in paths}, key=lambda d: len(d.parts), reverse=True):
        while d != prefix and d.is_dir() and not any(d.iterdir()):
            d.rmdir()
            d = d.parent


def install(pkg: str, prefix: pathlib.Path, build: pathlib.Path, gen: dict,
            libs: dict[str, pathlib.Path], digest: str) -> int:
    installed: list[pathlib.Path] = []

    def put(src: pathlib.Path, dst: pathlib.Path) -> None:
        dst.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(src, dst)
        installed.append(dst)

    def text(dst: pathlib.Path, content: str) -> None:
        dst.parent.mkdir(parents=True, exist_ok=True)
        dst.write_text(content)
        installed.append(dst)

    site = site_packages(prefix)
    share = prefix / 'share' / pkg
    # Python package
    pydir = build / 'py' / pkg
    for f in sorted(pydir.rglob('*.py')):
        put(f, site / pkg / f.relative_to(pydir))
    text(site / pkg / '__init__.py', '')
    for name, f in libs.items():
        put(f, (site / pkg / name) if name.startswith(pkg + '_s__') else prefix / 'lib' / name)
    # definitions, .idl, type descriptions (.json), package.xml
    src = HERE / pkg
    for f in interface_files(src):
        put(f, share / f.relative_to(src))
    for f in sorted(gen['idl_root'].rglob('*.idl')):
        put(f, share / f.relative_to(gen['idl_root']))
    for f in sorted(gen['td_root'].rglob('*.json')):
        put(f, share / f.relative_to(gen['td_root']))
    put(src / 'package.xml', share / 'package.xml')
    # headers (for C users; same layout as the wheels: include/<pkg>/<pkg>/msg/...)
    for g in ('c', 'typesupport_fastrtps_c', 'typesupport_introspection_c'):
        root = build / g
        for f in sorted((root / pkg).rglob('*.h')):
            put(f, prefix / 'include' / pkg / f.relative_to(root))
    # ament index
    index = prefix / 'share' / 'ament_index' / 'resource_index'
    text(index / 'packages' / pkg, '')
    entries = []
    for f in interface_files(src):
        rel = f.relative_to(src)
        entries += [str(rel.with_suffix('.idl')), str(rel)]
    text(index / 'rosidl_interfaces' / pkg, '\n'.join(entries))
    text(index / 'package_run_dependencies' / pkg,
         ';'.join(package_deps(pkg) + ['rosidl_default_runtime']))
    installed += [share / MANIFEST, share / STAMP]
    rel = sorted(str(p.relative_to(prefix)) for p in installed)
    (share / MANIFEST).write_text('\n'.join(rel) + '\n')
    (share / STAMP).write_text(digest + '\n')
    return len(installed)


# --------------------------------------------------------------------------- main

def state(pkg: str, prefix: pathlib.Path) -> tuple[str, str]:
    """('external', path) | ('ours', stamp) | ('absent', '')."""
    stamp = prefix / 'share' / pkg / STAMP
    spec = importlib.util.find_spec(pkg)
    if spec is None or spec.origin in (None, 'namespace'):  # a bare folder is no package
        return 'absent', ''
    origin = pathlib.Path(spec.submodule_search_locations[0] if spec.submodule_search_locations
                          else spec.origin or '').resolve()
    ours = site_packages(prefix).resolve() / pkg
    if origin == ours and stamp.exists():
        return 'ours', stamp.read_text().strip()
    if origin == ours:
        return 'absent', ''  # a half-installed leftover of ours: rebuild over it
    return 'external', str(origin)


def build_package(pkg: str, prefix: pathlib.Path, jobs: int, keep: bool) -> None:
    digest = inputs_digest(pkg)
    t0 = time.monotonic()
    build = pathlib.Path(tempfile.mkdtemp(prefix=f'rosidl_build_{pkg}_'))
    try:
        gen = generate(pkg, prefix, build, jobs)
        log(f'{pkg}: generated sources in {time.monotonic() - t0:.0f} s')
        libs = compile_and_link(pkg, prefix, build, jobs)
        uninstall(pkg, prefix)
        n = install(pkg, prefix, build, gen, libs, digest)
        log(f'{pkg}: built and installed {n} files into {prefix} in '
            f'{time.monotonic() - t0:.0f} s')
    finally:
        if keep:
            log(f'{pkg}: build tree kept in {build}')
        else:
            shutil.rmtree(build, ignore_errors=True)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('packages', nargs='*', metavar='pkg',
                    help=f'packages to build (default: {" ".join(PACKAGES)})')
    ap.add_argument('--prefix', type=pathlib.Path, default=pathlib.Path(sys.prefix),
                    help='install prefix, the venv (default: %(default)s)')
    ap.add_argument('--jobs', '-j', type=int, default=os.cpu_count() or 2)
    ap.add_argument('--force', action='store_true', help='rebuild even if up to date')
    ap.add_argument('--check', action='store_true',
                    help='only report; exit 1 if a package would be built')
    ap.add_argument('--keep-build', action='store_true', help='keep the build tree')
    ap.add_argument('--uninstall', action='store_true',
                    help='remove what this script installed, and exit')
    args = ap.parse_args(argv)
    unknown = set(args.packages) - set(PACKAGES)
    if unknown:
        ap.error(f'unknown package(s) {sorted(unknown)}; known: {PACKAGES}')
    prefix = args.prefix.resolve()
    logging.disable(logging.WARNING)  # rosidl_cli: duplicate entry points (harmless)
    # The generators find their templates through the ament index: use the venv's own,
    # never a sourced ROS install's (other versions).
    os.environ['AMENT_PREFIX_PATH'] = str(prefix)
    if args.uninstall:
        for pkg in args.packages or PACKAGES:
            uninstall(pkg, prefix)
        return 0
    needed = 0
    for pkg in args.packages or PACKAGES:
        kind, info = state(pkg, prefix)
        if kind == 'external':
            log(f'{pkg}: already importable from {info}; using it, not building')
            continue
        if kind == 'ours' and info == inputs_digest(pkg) and not args.force:
            continue
        needed += 1
        if args.check:
            log(f'{pkg}: would be built')
            continue
        build_package(pkg, prefix, args.jobs, args.keep_build)
    return 1 if (args.check and needed) else 0


if __name__ == '__main__':
    sys.exit(main())

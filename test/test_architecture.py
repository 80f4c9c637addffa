"""The rooms of docs/architecture.md: no forbidden import, no import cycle."""

import ast
import pathlib

import pytest

PACKAGE = pathlib.Path(__file__).resolve().parents[1] / 'st_stereo'
BAGS = {'bag_reading', 'bag_streams'}
# Room -> the other rooms it may import (docs/architecture.md, "The rooms").
ALLOWED = {
    'core': set(),
    'lepton': set(),
    'sim': {'core', 'lepton', 'package_data'},
    'package_data': set(),
    'bag_reading': set(),
    'bag_streams': {'core', 'bag_reading'},
    'nodes': {'core', 'lepton', 'package_data'} | BAGS,
    'launch_support': {'core', 'nodes', 'package_data'} | BAGS,
    'tools': {'core', 'lepton', 'sim', 'package_data', 'nodes', 'launch_support'} | BAGS,
    'cli': {'core', 'lepton', 'sim', 'package_data', 'nodes', 'tools', 'launch_support'} | BAGS,
    '__main__': {'cli'},
    '__init__': set(),
}
# Single modules a room may import outside its rooms (docs/architecture.md says why).
ALLOWED_MODULES = {
    'nodes': {'st_stereo.sim.plane'},      # the scene of the driver's source:=sim
}


def modules():
    """Return {dotted module name: path} of the package."""
    found = {}
    for path in PACKAGE.rglob('*.py'):
        parts = path.relative_to(PACKAGE.parent).with_suffix('').parts
        if parts[-1] == '__init__' and len(parts) > 2:
            parts = parts[:-1]
        found['.'.join(parts)] = path
    return found


def import_graph():
    """Return {module: {imported package modules}}, imports inside functions included."""
    known = modules()
    graph = {}
    for name, path in known.items():
        targets = set()
        for node in ast.walk(ast.parse(path.read_text(encoding='utf-8'), str(path))):
            if isinstance(node, ast.Import):
                candidates = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                candidates = [node.module] + [f'{node.module}.{a.name}' for a in node.names]
            else:
                continue
            targets |= {c for c in candidates if c in known and c != name}
        graph[name] = targets
    return graph


def room(module):
    """Return the room of a module: its subpackage, or the top-level module's name."""
    return module.split('.')[1] if module.count('.') else '__init__'


def test_no_room_imports_one_it_may_not():
    forbidden = sorted(
        (module, target) for module, targets in import_graph().items() for target in targets
        if room(target) != room(module) and room(target) not in ALLOWED[room(module)]
        and target not in ALLOWED_MODULES.get(room(module), ()))
    assert not forbidden, 'imports docs/architecture.md forbids: ' + ', '.join(
        f'{module} -> {target}' for module, target in forbidden)


def test_every_room_is_named_in_the_rules():
    assert {room(module) for module in modules()} <= set(ALLOWED)


def find_cycles(graph):
    """Return the strongly connected components of more than one module (Tarjan)."""
    index, low, stack, on_stack, cycles = {}, {}, [], set(), []

    def visit(node):
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for target in graph.get(node, ()):
            if target not in index:
                visit(target)
                low[node] = min(low[node], low[target])
            elif target in on_stack:
                low[node] = min(low[node], index[target])
        if low[node] == index[node]:
            component = []
            while True:
                member = stack.pop()
                on_stack.discard(member)
                component.append(member)
                if member == node:
                    break
            if len(component) > 1:
                cycles.append(sorted(component))
    for node in sorted(graph):
        if node not in index:
            visit(node)
    return cycles


def test_there_is_no_import_cycle():
    assert find_cycles(import_graph()) == []


@pytest.mark.parametrize('graph, cycles', [
    ({'a': {'b'}, 'b': {'a'}, 'c': {'a'}}, [['a', 'b']]),
    ({'a': {'b'}, 'b': {'c'}, 'c': set()}, []),
])
def test_the_cycle_finder_finds_cycles(graph, cycles):
    assert find_cycles(graph) == cycles


def test_the_rules_catch_a_forbidden_import(tmp_path, monkeypatch):
    # The check itself: a core module importing a node is reported.
    fake = tmp_path / 'st_stereo'
    (fake / 'core').mkdir(parents=True)
    (fake / 'nodes').mkdir()
    (fake / 'core' / 'bad.py').write_text('from st_stereo.nodes import thing\n')
    (fake / 'nodes' / 'thing.py').write_text('')
    (fake / 'nodes' / '__init__.py').write_text('')
    monkeypatch.setattr(__import__(__name__), 'PACKAGE', fake)
    with pytest.raises(AssertionError, match='st_stereo.core.bad -> st_stereo.nodes'):
        test_no_room_imports_one_it_may_not()


def test_nodes_may_use_the_drivers_plane_scene_only(tmp_path, monkeypatch):
    fake = tmp_path / 'st_stereo'
    for room_name in ('nodes', 'sim'):
        (fake / room_name).mkdir(parents=True)
        (fake / room_name / '__init__.py').write_text('')
    (fake / 'sim' / 'plane.py').write_text('')
    (fake / 'sim' / 'render.py').write_text('')
    (fake / 'nodes' / 'driver_node.py').write_text('from st_stereo.sim.plane import x\n')
    monkeypatch.setattr(__import__(__name__), 'PACKAGE', fake)
    test_no_room_imports_one_it_may_not()
    (fake / 'nodes' / 'other_node.py').write_text('from st_stereo.sim.render import y\n')
    with pytest.raises(AssertionError, match='st_stereo.nodes.other_node -> st_stereo.sim.render'):
        test_no_room_imports_one_it_may_not()

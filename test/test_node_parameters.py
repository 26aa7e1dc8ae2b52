"""The node's parameter rules without DDS (core/ros_data/node_parameters.py): what counts as a
change, how rejected values are shown, unknown names, and user text without issue numbers."""
import ast
import re
from pathlib import Path

from zeroshot_calib_ros.core.ros_data.node_parameters import (PARAMETERS, changed_parameters,
                                                               unknown_parameter_warnings, usage_text, value_text)
from zeroshot_calib_ros.core.zeroshot.spec import SpecError

PACKAGE = Path(__file__).resolve().parents[1] / 'zeroshot_calib_ros'


def test_a_change_is_a_change_only_when_a_value_differs():
    current = {name: p.default for name, p in PARAMETERS.items()}
    current.update(hfov=115.0, width=1920, projection='auto', rectify=False)
    # ros2 param load of a dump, ros2 param set hfov 115 (an INTEGER for a double parameter)
    assert changed_parameters(current, [('hfov', 115), ('width', 1920), ('projection', 'auto'),
                                        ('rectify', False)]) == []
    assert changed_parameters(current, [('hfov', 115.0), ('width', 1920.0)]) == []
    assert changed_parameters(current, [('hfov', 115.5), ('width', 1920)]) == ['hfov']
    # typed: a bool is not a number, a string is not a number
    assert changed_parameters(current, [('rectify', 0)]) == ['rectify']
    assert changed_parameters(current, [('width', True), ('hfov', '115')]) == ['width', 'hfov']
    assert changed_parameters(current, [('refine', False), ('refine_interval', 2)]) == []


def test_rejected_values_are_shown_cut_to_a_bounded_length():
    huge = 'x' * 1_000_000
    text = value_text(huge)
    assert len(text) < 120 and text.endswith('... (1000000 characters)'), text
    assert value_text('plumb') == "'plumb'" and value_text(115.5) == '115.5'
    message = str(SpecError('projection', huge, 'one of: auto, equidistant'))
    assert len(message) < 200 and '1000000 characters' in message and 'projection' in message, message


def test_unknown_parameters_are_named_with_the_closest_declared_one():
    warnings = unknown_parameter_warnings(['rectfy', 'hfov', 'qos_overrides./camera_info.publisher.depth',
                                          'use_sim_time', 'zzzzzz'])
    assert len(warnings) == 2, warnings
    assert "'rectfy'" in warnings[0] and "did you mean 'rectify'" in warnings[0], warnings
    assert "'zzzzzz'" in warnings[1] and 'did you mean' not in warnings[1], warnings


def _user_strings():
    """Every string literal of the package but docstrings and comments."""
    for path in PACKAGE.rglob('*.py'):
        tree = ast.parse(path.read_text())
        docstrings = {id(node.body[0].value) for node in ast.walk(tree)
                      if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef))
                      and node.body and isinstance(node.body[0], ast.Expr)
                      and isinstance(node.body[0].value, ast.Constant)}
        for node in ast.walk(tree):
            if isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in docstrings:
                yield path, node.lineno, node.value


def test_user_text_has_no_issue_numbers():
    found = [f'{path.name}:{line}: {text[:60]!r}' for path, line, text in _user_strings()
             if re.search(r'\bissues?\s*#?\d', text, re.IGNORECASE)]
    assert not found, found
    assert not re.search(r'\bissue\s*#?\d', usage_text(), re.IGNORECASE)

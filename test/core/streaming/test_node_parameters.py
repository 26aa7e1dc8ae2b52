"""The node's parameter rules without DDS (core/streaming/node_parameters.py): what counts as a
change, how rejected values are shown, unknown names, and user text without issue numbers."""
import ast
import re
from pathlib import Path

from zeroshot_calib_ros.core.streaming.node_parameters import (PARAMETERS, changed_parameters, params_file_errors,
                                                               unknown_parameter_warnings, usage_text, value_text)
from zeroshot_calib_ros.core.zeroshot.spec import SpecError

PACKAGE = Path(__file__).resolve().parents[3] / 'zeroshot_calib_ros'


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


def test_a_params_file_that_cannot_be_read_is_one_line_naming_it(tmp_path):
    """--params-file FILE of the ROS arguments: a missing file and a directory are each one line
    naming the path and what it is; a readable file is no error; arguments before --ros-args
    (or after --) are not ROS arguments."""
    readable = tmp_path / 'params.yaml'
    readable.write_text('/**:\n  ros__parameters:\n    hfov: 118.0\n')
    missing = tmp_path / 'missing.yaml'
    assert params_file_errors(['--ros-args', '--params-file', str(readable)]) == []
    for path, what in ((missing, 'no such file'), (tmp_path, 'is a directory')):
        errors = params_file_errors(['--ros-args', '--params-file', str(path)])
        assert len(errors) == 1 and str(path) in errors[0] and what in errors[0], errors
        assert '\n' not in errors[0]
    assert params_file_errors(['--params-file', str(tmp_path), '--ros-args']) == []
    assert params_file_errors(['--ros-args', '--', '--params-file', str(tmp_path)]) == []
    both = params_file_errors(['--ros-args', '--params-file', str(tmp_path), '--params-file', str(missing)])
    assert len(both) == 2 and str(tmp_path) in both[0] and str(missing) in both[1], both


def test_params_file_as_the_last_argument_says_it_needs_a_file():
    """`node --ros-args --params-file` with nothing after it: one line saying a file is needed
    (not an IndexError)."""
    for argv in (['--ros-args', '--params-file'], ['-x', '--ros-args', '-p', 'hfov:=118', '--params-file']):
        errors = params_file_errors(argv)
        assert len(errors) == 1 and errors[0].startswith('--params-file needs a file'), errors


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

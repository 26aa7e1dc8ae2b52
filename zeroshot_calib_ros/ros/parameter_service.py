"""rclpy's parameter services with SetParameters as one atomic change, and the node's parameter
table (core/streaming/node_parameters.py) as ROS ParameterDescriptors."""
from __future__ import annotations

from rcl_interfaces.msg import (FloatingPointRange, IntegerRange, ParameterDescriptor, ParameterType,
                                SetParametersResult)
from rclpy.exceptions import ParameterNotDeclaredException
from rclpy.parameter import Parameter
from rclpy.parameter_service import ParameterService

from ..core.streaming.node_parameters import NodeParameter, closest_parameter_text, same_value
from ..core.zeroshot.spec import value_text

_TYPES = {'bool': ParameterType.PARAMETER_BOOL, 'integer': ParameterType.PARAMETER_INTEGER,
          'double': ParameterType.PARAMETER_DOUBLE, 'string': ParameterType.PARAMETER_STRING}


def descriptor(parameter: NodeParameter) -> ParameterDescriptor:
    """The ROS descriptor of one parameter of the table."""
    d = ParameterDescriptor(description=parameter.description, type=_TYPES[parameter.type],
                            read_only=parameter.read_only, additional_constraints=parameter.constraints,
                            dynamic_typing=parameter.dynamic)
    if parameter.range and parameter.type == 'double':
        d.floating_point_range = [FloatingPointRange(from_value=parameter.range[0], to_value=parameter.range[1])]
    elif parameter.range and parameter.type == 'integer':
        d.integer_range = [IntegerRange(from_value=parameter.range[0], to_value=parameter.range[1], step=1)]
    return d


_TYPE_TEXT = {ParameterType.PARAMETER_BOOL: 'true or false', ParameterType.PARAMETER_INTEGER: 'an integer',
              ParameterType.PARAMETER_DOUBLE: 'a number', ParameterType.PARAMETER_STRING: 'a string'}


class AtomicParameterService(ParameterService):
    """rclpy's parameter services, except that one SetParameters request (``ros2 param set``,
    ``ros2 param load``) is one change: validated together, solved once, adopted whole or
    rejected whole. rclpy applies such a request value by value, which adopts intermediate
    calibrations nobody asked for (a new width with the old height). Read-only parameters given
    their current value (a params file loaded back) are no change and succeed."""

    def _set_parameters_callback(self, request, response):
        parameters = [Parameter.from_parameter_msg(p) for p in request.parameters]
        result, unchanged = self._apply(parameters)
        # Whole: a rejected request rejects its unchanged read-only values too, so that no client
        # reads one result as "this part was applied"; every result gives the reason.
        response.results = [SetParametersResult(successful=True, reason='unchanged (read-only)')
                            if i in unchanged and result.successful else
                            SetParametersResult(successful=result.successful, reason=result.reason)
                            for i in range(len(parameters))]
        return response

    def _set_parameters_atomically_callback(self, request, response):
        """SetParametersAtomically (one result) by the same rules as SetParameters."""
        response.result = self._apply([Parameter.from_parameter_msg(p) for p in request.parameters])[0]
        return response

    def _apply(self, parameters) -> tuple:
        """(one SetParametersResult for the whole request, indices of unchanged read-only values)."""
        node = self._get_node()
        # rclpy's own check names only some undeclared names (often none: "[]"): named here,
        # each with the closest declared name
        undeclared = [p.name for p in parameters if not node.has_parameter(p.name)]
        unchanged = set()
        for i, param in enumerate(parameters):
            if param.name not in undeclared and node.describe_parameter(param.name).read_only and \
                    same_value(param.name, node.get_parameter(param.name).value, param.value):
                unchanged.add(i)
        changes = [p for i, p in enumerate(parameters) if i not in unchanged]
        wrong_type = next((text for text in map(self._wrong_type, changes) if text), None)
        try:
            if undeclared:
                result = SetParametersResult(successful=False, reason='; '.join(
                    f'undeclared parameter {value_text(name)}{closest_parameter_text(name)}' for name in undeclared)
                    + ': the whole request was rejected')
            elif wrong_type:  # rclpy's reason would not name the parameter
                result = SetParametersResult(successful=False, reason=wrong_type)
            else:
                result = node.set_parameters_atomically(changes) if changes else SetParametersResult(successful=True)
        except ParameterNotDeclaredException as exc:
            result = SetParametersResult(successful=False, reason=f'{exc}: the whole request was rejected')
        if not result.successful and not result.reason:
            result.reason = 'rejected'
        return result, unchanged

    def _wrong_type(self, param: Parameter) -> str:
        """The reason a value of the wrong type for a statically typed parameter is rejected, naming
        the parameter as the node's own checks do ('' if the type is right or rclpy decides)."""
        node = self._get_node()
        if not node.has_parameter(param.name):
            return ''
        descriptor = node.describe_parameter(param.name)
        if descriptor.dynamic_typing or descriptor.read_only or param.type_.value == descriptor.type:
            return ''
        value = param.value if not hasattr(param.value, 'tolist') else param.value.tolist()
        allowed = _TYPE_TEXT.get(descriptor.type, Parameter.Type(descriptor.type).name.lower())
        if descriptor.additional_constraints:
            allowed += f' ({descriptor.additional_constraints})'
        return f'{param.name} = {value_text(value)} is invalid: allowed: {allowed}'

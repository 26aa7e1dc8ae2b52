"""The node's /diagnostics status and its state texts, from the node's state, without ROS.

The node (``zeroshot_calib_ros/ros/node.py``) turns a ``Status`` into a
diagnostic_msgs/DiagnosticStatus (``level`` names one of its constants: OK, WARN, ERROR) and
publishes it once a second; the same texts go into its start-up log (``rectify_text``,
``frame_path_text``)."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Tuple

from .image_frames import ActiveCalibration


@dataclass
class Status:
    """One DiagnosticStatus: ``level`` is 'OK', 'WARN' or 'ERROR'; ``values`` in publishing order."""
    level: str
    name: str
    hardware_id: str
    message: str
    values: dict


def rectify_text(rectify_enabled: bool, subscribers: int, ever_subscribed: bool) -> str:
    """'off', 'on, lazy: no subscriber yet', 'on, lazy: no subscriber', 'on: 1 subscriber'."""
    if not rectify_enabled:
        return 'off'
    if subscribers:
        return f'on: {subscribers} subscriber{"s" if subscribers > 1 else ""}'
    return 'on, lazy: no subscriber' + ('' if ever_subscribed else ' yet')


def frame_path_text(serialized: bool, reason: str) -> str:
    """The frame path in use and why (the start-up log)."""
    if serialized:
        return ('serialized: image_raw taken as CDR bytes, image_rect and camera_info published as bytes'
                + (f' ({reason})' if reason else ''))
    return f'message: sensor_msgs/Image objects ({reason})'


def refine_values(refiner_values: Optional[dict], refine_off: str) -> dict:
    """The ``refine_*`` diagnostics: from a running refiner's ``status.values()``, or why none runs."""
    if refiner_values is None:
        return {'refine_state': 'off', 'refine_reason': refine_off}
    values = refiner_values
    return {'refine_state': values['state'], 'refine_reason': values['reason'],
            'refine_frames': values['frames_processed'], 'refine_adopted': values['cameras_offered'],
            'refine_lines': values['lines'],
            'refine_coverage': values['coverage'], 'refine_residual_px': values['residual_px'],
            'refine_uncertainty_px': values['uncertainty_px'],
            'refine_zero_shot_uncertainty_px': values['zero_shot_uncertainty_px']}


def calibration_status(node_name: str, active: ActiveCalibration, *, serialized: bool, frame_path_reason: str,
                       executor: str, rectify: str, rect_subscribers: int, qos_reliability: str,
                       pending_generation, maps_build_ms: float, process_rss_bytes: int, refine: dict,
                       stats: dict, uncalibrated: Optional[Tuple[Tuple[int, int], str]]) -> Status:
    """The calibration's status: OK; WARN while the refiner has failed or the spec's FOVs do not
    fit the image; ERROR while frames come that no calibration describes (``uncalibrated``:
    (size, why)), named in the message."""
    status = Status(level='OK', name=f'{node_name}: calibration', hardware_id=active.calibration.camera_name,
                    message=f'calibration from {active.source}', values={})
    values = {'source': active.source, 'generation': active.generation,
              'frame_path': 'serialized' if serialized else f'message ({frame_path_reason})',
              'executor': executor,
              'rectify': rectify, 'image_rect_subscribers': rect_subscribers,
              'frames_rectified': 0, 'frames_not_rectified_no_subscriber': 0,
              'fx': active.calibration.K[0, 0], 'qos_reliability': qos_reliability,
              'pending_generation': pending_generation,
              'maps_build_ms': f'{maps_build_ms:.1f}',
              'map_memory_mb': f'{active.map_memory_bytes / 2**20:.1f}',
              'frame_buffer_mb': f'{active.frame_buffer_bytes / 2**20:.1f}',
              'process_rss_mb': f'{process_rss_bytes / 2**20:.1f}', **refine,
              **stats}
    if values['refine_state'] == 'failed':
        status.level = 'WARN'
    if active.spec_warnings:  # a calibration from a spec whose FOVs it does not show
        status.level = 'WARN'
        status.message += ": the spec's FOVs do not fit the image (spec_warning)"
        values['spec_warning'] = ' | '.join(active.spec_warnings)
    if active.assumption:  # usable, only less certain: said, not a WARN level
        values['assumption'] = active.assumption
    if uncalibrated is not None:
        (width, height), why = uncalibrated
        status.level = 'ERROR'
        status.message = f'no CameraInfo for the {width}x{height} frames: {why}'
    status.values = values
    return status

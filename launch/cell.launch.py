"""The cell with its real hardware: the camera and the motor controller.

    ros2 launch sfs_ros cell.launch.py output_dir:=/data/scans [namespace:=/sfs] \
        [port:=/dev/ttyUSB0] [camera_device:=/dev/video2 | camera_topic:=/usb_cam/image_raw] \
        [params_file:=my_cell.yaml]

The same nodes, params files and overrides as ``sfs-cell -o OUTPUT_DIR``
(``sfs_ros.cli.bringup.cell_nodes(..., mock=False)``); the state publisher
(``sfs-state-publisher``) publishes the cell's TF.
With ``camera_topic`` another driver's frames are the views: our camera node
is not started and the scan node streams from that topic. The motor and camera
are managed (lifecycle) nodes started unconfigured (``autostart`` false); the
lifecycle manager (``sfs-lifecycle-manager``) configures and activates them in
order, the motor first, and again when one is respawned.
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch.actions import DeclareLaunchArgument, SetEnvironmentVariable
from launch.conditions import IfCondition
from launch.substitutions import (
    EnvironmentVariable,
    EqualsSubstitution,
    LaunchConfiguration,
    NotEqualsSubstitution,
    PathJoinSubstitution,
)
from launch_ros.actions import Node

from launch import LaunchDescription
from sfs_ros.process import KEEP_FREED_MEMORY_ENVIRONMENT, STOP_GRACE_S

#: Seconds before a node that ended by itself is started again.
RESPAWN_DELAY_S = 2.0


def generate_launch_description():
    share = get_package_share_directory('sfs_ros')
    config = os.path.join(share, 'config')
    output_dir = LaunchConfiguration('output_dir')
    namespace = LaunchConfiguration('namespace')
    params_file = LaunchConfiguration('params_file')
    camera_topic = LaunchConfiguration('camera_topic')
    own_camera = IfCondition(EqualsSubstitution(camera_topic, ''))
    other_camera = IfCondition(NotEqualsSubstitution(camera_topic, ''))
    # As sfs-cell: a node finishes its queued work on SIGINT (a mesh's pictures), and
    # launch's own default gives it 5 s before SIGTERM. A sigterm_timeout:= or
    # sigkill_timeout:= given to ros2 launch wins.
    stop_grace = {'sigterm_timeout': LaunchConfiguration('sigterm_timeout',
                                                         default=str(STOP_GRACE_S)),
                  'sigkill_timeout': LaunchConfiguration('sigkill_timeout',
                                                         default=str(STOP_GRACE_S))}
    return LaunchDescription([
        DeclareLaunchArgument('output_dir',
                              description='Folder of the scans, meshes and reports'),
        DeclareLaunchArgument('namespace', default_value='/sfs',
                              description='ROS namespace of all nodes'),
        DeclareLaunchArgument('params_file', default_value=os.path.join(config, 'overrides.yaml'),
                              description="YAML parameters given to every node after its own "
                                          "files (default: overrides.yaml, which sets nothing)"),
        # As sfs-cell (bringup.DDS_ENVIRONMENT): UDP, since Fast DDS's shared memory can
        # leave a respawned node deaf to the nodes that outlived its predecessor.
        SetEnvironmentVariable('FASTDDS_BUILTIN_TRANSPORTS', EnvironmentVariable(
            'FASTDDS_BUILTIN_TRANSPORTS', default_value='UDPv4')),
        # As sfs-cell (sfs_ros.process.PROCESS_ENVIRONMENT): in place before NumPy loads BLAS.
        SetEnvironmentVariable('OPENBLAS_NUM_THREADS', EnvironmentVariable(
            'OPENBLAS_NUM_THREADS', default_value='1')),
        # and before numba loads OpenMP, whose threads then wait asleep.
        SetEnvironmentVariable('OMP_WAIT_POLICY', EnvironmentVariable(
            'OMP_WAIT_POLICY', default_value='PASSIVE')),
        DeclareLaunchArgument('port', default_value='/dev/ttyACM0',
                              description="The motor controller's serial port"),
        DeclareLaunchArgument('camera_device', default_value='0',
                              description="Our camera node's device: index, /dev/videoN, file "
                                          "or URL"),
        DeclareLaunchArgument('camera_topic', default_value='',
                              description="Image topic of another camera driver (usb_cam, "
                                          "v4l2_camera, GenICam): then our camera node is not "
                                          "started and the scan takes that topic's frames"),
        Node(package='sfs_ros', executable='sfs-camera', name='camera', namespace=namespace,
             output='screen', respawn=True, respawn_delay=RESPAWN_DELAY_S, condition=own_camera,
             parameters=[os.path.join(config, 'rig.yaml'), os.path.join(config, 'frames.yaml'),
                         os.path.join(config, 'camera.yaml'), params_file,
                         {'device': LaunchConfiguration('camera_device'), 'autostart': False}],
             **stop_grace),
        Node(package='sfs_ros', executable='sfs-motor', name='motor', namespace=namespace,
             output='screen', respawn=True, respawn_delay=RESPAWN_DELAY_S,
             parameters=[os.path.join(config, 'motor.yaml'), params_file,
                         {'port': LaunchConfiguration('port'), 'autostart': False}], **stop_grace),
        Node(package='sfs_ros', executable='sfs-lifecycle-manager', name='lifecycle_manager',
             namespace=namespace, output='screen', respawn=True, respawn_delay=RESPAWN_DELAY_S,
             condition=own_camera, parameters=[params_file, {'nodes': ['motor', 'camera']}],
             **stop_grace),
        Node(package='sfs_ros', executable='sfs-lifecycle-manager', name='lifecycle_manager',
             namespace=namespace, output='screen', respawn=True, respawn_delay=RESPAWN_DELAY_S,
             condition=other_camera, parameters=[params_file, {'nodes': ['motor']}], **stop_grace),
        # The cell's TF (/tf, /tf_static) and URDF (robot_description) from the motor node's
        # joint_states, the rig and the frames (config/frames.yaml).
        Node(package='sfs_ros', executable='sfs-state-publisher', name='state_publisher',
             namespace=namespace, output='screen', respawn=True, respawn_delay=RESPAWN_DELAY_S,
             parameters=[os.path.join(config, 'rig.yaml'), os.path.join(config, 'frames.yaml'),
                         params_file], **stop_grace),
        Node(package='sfs_ros', executable='sfs-segmentation', name='segmentation',
             namespace=namespace, output='screen', respawn=True, respawn_delay=RESPAWN_DELAY_S,
             parameters=[os.path.join(config, 'rig.yaml'),
                         os.path.join(config, 'segmentation.yaml'), params_file], **stop_grace),
        Node(package='sfs_ros', executable='sfs-carving', name='carving',
             additional_env=KEEP_FREED_MEMORY_ENVIRONMENT,
             namespace=namespace, output='screen', respawn=True, respawn_delay=RESPAWN_DELAY_S,
             parameters=[os.path.join(config, 'rig.yaml'), os.path.join(config, 'frames.yaml'),
                         os.path.join(config, 'carving.yaml'), params_file,
                         {'output_dir': output_dir}], **stop_grace),
        Node(package='sfs_ros', executable='sfs-meshing', name='meshing',
             additional_env=KEEP_FREED_MEMORY_ENVIRONMENT,
             namespace=namespace, output='screen', respawn=True, respawn_delay=RESPAWN_DELAY_S,
             parameters=[os.path.join(config, 'frames.yaml'),
                         os.path.join(config, 'meshing.yaml'), params_file,
                         {'output_dir': output_dir}], **stop_grace),
        Node(package='sfs_ros', executable='sfs-recorder', name='recorder',
             namespace=namespace, output='screen', respawn=True, respawn_delay=RESPAWN_DELAY_S,
             parameters=[os.path.join(config, 'recorder.yaml'), params_file,
                         {'output_dir': output_dir}], **stop_grace),
        Node(package='sfs_ros', executable='sfs-calibration', name='calibration',
             namespace=namespace, output='screen', respawn=True, respawn_delay=RESPAWN_DELAY_S,
             parameters=[os.path.join(config, 'calibration.yaml'), params_file,
                         {'output_dir': output_dir,
                          'plan_file': os.path.join(config, 'calibration_plan.yaml')}],
             **stop_grace),
        Node(package='sfs_ros', executable='sfs-scan', name='scan', namespace=namespace,
             output='screen', respawn=True, respawn_delay=RESPAWN_DELAY_S, condition=own_camera,
             parameters=[os.path.join(config, 'scan.yaml'), params_file,
                         {'plan_file': os.path.join(config, 'scan_plan.yaml'),
                          'progress_dir': PathJoinSubstitution([output_dir, 'scan_progress'])}],
             **stop_grace),
        # Another driver's camera: the scan node takes its streamed frames.
        Node(package='sfs_ros', executable='sfs-scan', name='scan', namespace=namespace,
             output='screen', respawn=True, respawn_delay=RESPAWN_DELAY_S,
             condition=other_camera, remappings=[('image_raw', camera_topic)],
             parameters=[os.path.join(config, 'scan.yaml'), params_file,
                         {'plan_file': os.path.join(config, 'scan_plan.yaml'),
                          'camera_trigger': 'stream',
                          'progress_dir': PathJoinSubstitution([output_dir, 'scan_progress'])}],
             **stop_grace),
    ])

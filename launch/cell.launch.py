"""The cell with its real hardware: the camera and the motor controller (motor.yaml's port).

    ros2 launch sfs_ros cell.launch.py output_dir:=/data/scans [namespace:=/cell1]

The same nodes, params files and overrides as ``sfs-cell -o OUTPUT_DIR``
(``sfs_ros.cli.bringup.cell_nodes(..., mock=False)``), plus robot_state_publisher
(the TF of ``urdf/sfs_cell.urdf``; it is not on PyPI, so ``sfs-cell`` has no TF).
"""

import os
from pathlib import Path

from ament_index_python.packages import get_package_share_directory
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import Node

from launch import LaunchDescription

#: Seconds before a node that ended by itself is started again.
RESPAWN_DELAY_S = 2.0


def generate_launch_description():
    share = get_package_share_directory('sfs_ros')
    config = os.path.join(share, 'config')
    robot_description = Path(os.path.join(share, 'urdf', 'sfs_cell.urdf')).read_text()
    output_dir = LaunchConfiguration('output_dir')
    namespace = LaunchConfiguration('namespace')
    return LaunchDescription([
        DeclareLaunchArgument('output_dir',
                              description='Folder of the scans, meshes and reports'),
        DeclareLaunchArgument('namespace', default_value='',
                              description='ROS namespace of all nodes'),
        Node(package='sfs_ros', executable='sfs-camera', name='camera', namespace=namespace,
             output='screen', respawn=True, respawn_delay=RESPAWN_DELAY_S,
             parameters=[os.path.join(config, 'rig.yaml'), os.path.join(config, 'camera.yaml')]),
        Node(package='sfs_ros', executable='sfs-motor', name='motor', namespace=namespace,
             output='screen', respawn=True, respawn_delay=RESPAWN_DELAY_S,
             parameters=[os.path.join(config, 'motor.yaml')]),
        Node(package='sfs_ros', executable='sfs-segmentation', name='segmentation',
             namespace=namespace, output='screen', respawn=True, respawn_delay=RESPAWN_DELAY_S,
             parameters=[os.path.join(config, 'segmentation.yaml')]),
        Node(package='sfs_ros', executable='sfs-reconstruction', name='reconstruction',
             namespace=namespace, output='screen', respawn=True, respawn_delay=RESPAWN_DELAY_S,
             parameters=[os.path.join(config, 'rig.yaml'),
                         os.path.join(config, 'reconstruction.yaml'),
                         {'output_dir': output_dir}]),
        Node(package='sfs_ros', executable='sfs-recorder', name='recorder',
             namespace=namespace, output='screen', respawn=True, respawn_delay=RESPAWN_DELAY_S,
             parameters=[os.path.join(config, 'recorder.yaml'), {'output_dir': output_dir}]),
        Node(package='sfs_ros', executable='sfs-scan', name='scan', namespace=namespace,
             output='screen', respawn=True, respawn_delay=RESPAWN_DELAY_S,
             parameters=[os.path.join(config, 'scan.yaml'),
                         {'plan_file': os.path.join(config, 'scan_plan.yaml'),
                          'progress_dir': PathJoinSubstitution([output_dir, 'scan_progress'])}]),
        # TF of the cell (base_link, turntable, carriage, camera_optical) from the motor
        # node's joint_states; the URDF is made from config/rig.yaml's defaults.
        Node(package='robot_state_publisher', executable='robot_state_publisher',
             name='robot_state_publisher', namespace=namespace, output='screen',
             respawn=True, respawn_delay=RESPAWN_DELAY_S,
             parameters=[{'robot_description': robot_description}]),
    ])

"""Start the node ``tensegrity_sim`` (and, with ``rviz:=true``, RViz with the shipped view).

    ros2 launch tensegrity_ros tensegrity.launch.py
    ros2 launch tensegrity_ros tensegrity.launch.py scene_file:=config/scenes/lens_array.yaml \\
        real_time_factor:=0.5 record_mcap:=runs/launch namespace:=lab rviz:=true

Every argument of :data:`NODE_ARGUMENTS` is a parameter of the node by the same name (given after
the parameters file, so it wins); ``params_file`` defaults to the installed ``config/node.yaml``.
A relative ``scene_file`` is looked up in the working directory, then in the package's share
directory. ``use_sim_time`` may be true for every node of a launch: the node steps on the wall
clock and publishes ``/clock`` itself (docs/node.md).
"""
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue
from launch_ros.substitutions import FindPackageShare

PACKAGE = 'tensegrity_ros'
EXECUTABLE = 'tensegrity_node'
NODE_NAME = 'tensegrity_sim'
RVIZ_CONFIG = 'config/tensegrity.rviz'
# launch argument -> (default, type of the node parameter, description)
NODE_ARGUMENTS = {
    'scene_file': ('config/scenes/fb_column.yaml', str, 'scene YAML of the simulation'),
    'real_time_factor': ('1.0', float, 'simulated seconds per wall second; 0 = as fast as '
                         'possible'),
    'record_mcap': ('', str, 'rosbag2 bag folder (MCAP) to record every topic to; empty = none'),
    'record_rerun': ('', str, 'Rerun .rrd file to record to; empty = none'),
    'start_paused': ('false', bool, 'start with the clock stopped (~/set_running, ~/step)'),
    'use_sim_time': ('false', bool, "the node's ROS clock from /clock (which it publishes)"),
}
# launch arguments that are not node parameters
OTHER_ARGUMENTS = {
    'namespace': ('tensegrity', 'namespace of the node (topics /<namespace>/tensegrity_sim/...)'),
    'params_file': (None, 'parameters file (default: the installed config/node.yaml)'),
    'rviz': ('false', 'also start RViz with the shipped view config/tensegrity.rviz'),
}


def generate_launch_description():
    share = FindPackageShare(PACKAGE)
    declared = [DeclareLaunchArgument(name, default_value=default, description=text)
                for name, (default, _, text) in NODE_ARGUMENTS.items()]
    for name, (default, text) in OTHER_ARGUMENTS.items():
        if default is None:
            default = PathJoinSubstitution([share, 'config', 'node.yaml'])
        declared.append(DeclareLaunchArgument(name, default_value=default, description=text))
    overrides = {name: ParameterValue(LaunchConfiguration(name), value_type=kind)
                 for name, (_, kind, _) in NODE_ARGUMENTS.items()}
    node = Node(package=PACKAGE, executable=EXECUTABLE, name=NODE_NAME,
                namespace=LaunchConfiguration('namespace'), output='screen', emulate_tty=True,
                parameters=[LaunchConfiguration('params_file'), overrides])
    rviz = Node(package='rviz2', executable='rviz2', name='rviz2', output='screen',
                arguments=['-d', PathJoinSubstitution([share, RVIZ_CONFIG])],
                parameters=[{'use_sim_time': ParameterValue(LaunchConfiguration('use_sim_time'),
                                                            value_type=bool)}],
                condition=IfCondition(LaunchConfiguration('rviz')))
    return LaunchDescription(declared + [node, rviz])

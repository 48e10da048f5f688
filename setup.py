"""tensegrity_ros: impact waves in tensegrity metamaterials, streamed over ROS 2."""
from glob import glob

from setuptools import find_packages, setup

package_name = 'tensegrity_ros'

# ROS 2 Kilted from PyPI wheels (cp311), the `ros` extra: `pip install -e '.[ros]'`. Users with a
# ROS distribution install without it (`pip install -e .`, or colcon with package.xml).
ROS_WHEELS = [
    'ros-rclpy==9.1.2',
    'ros-std-msgs==5.5.1',
    'ros-sensor-msgs==5.5.1',
    'ros-geometry-msgs==5.5.1',
    'ros-visualization-msgs==5.5.1',
    'ros-rosgraph-msgs==2.3.0',
    'ros-std-srvs==5.5.1',
    'ros-diagnostic-msgs==5.5.1',
    'ros-lifecycle-msgs==2.3.0',
    'ros-rcl-lifecycle==10.1.3',
    'ros-rmw-fastrtps-cpp==9.3.3',
]
CORE = [
    'numpy==2.4.6',
    'numba==0.68.1',
    'scipy==1.17.1',
    'pyyaml==6.0.3',
    'matplotlib==3.11.2',
    'tqdm==4.70.1',
    'mcap==1.6.0',
    'mcap-ros2-support==0.6.0',
    'rerun-sdk==0.41.0',
    'dask==2026.8.0',
    'distributed==2026.8.0',
    'pyarrow==26.0.1',
]

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(include=['solver', 'solver.*', package_name, package_name + '.*']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        # everything the docs use from a checkout, so that an install finds it too: the node's
        # parameters, the RViz and Foxglove views, the scenes, the paper's targets, the launch file
        ('share/' + package_name + '/config', sorted(glob('config/*.yaml') + glob('config/*.rviz')
                                                     + glob('config/*.json'))),
        ('share/' + package_name + '/config/scenes', sorted(glob('config/scenes/*.yaml'))),
        ('share/' + package_name + '/config/paper', sorted(glob('config/paper/*.yaml'))),
        ('share/' + package_name + '/launch', sorted(glob('launch/*.launch.py'))),
    ],
    install_requires=CORE,
    extras_require={
        'ros': ROS_WHEELS,
        'test': ['pytest==9.2.0', 'pytest-xdist==3.8.0', 'execnet==2.1.2', 'ruff==0.17.6',
                 'rosbags==0.11.9'],
        'peers': ['mujoco==4.0.0'],
    },
    python_requires='>=3.11',
    zip_safe=False,
    maintainer='tensegrity_ros developers',
    maintainer_email='tensegrity-ros@users.noreply.github.com',
    description='Simulation of tensegrity metamaterials as virtual acoustic actuators, over ROS 2',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'tensegrity = tensegrity_ros.cli:main',
            'tensegrity_node = tensegrity_ros.node.node:main',
        ],
    },
)

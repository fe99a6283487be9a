# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""Install the kraft_master_driver ament_python package."""
from glob import glob

from setuptools import find_packages, setup

package_name = 'kraft_master_driver'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'benchmarks']),
    # PEP 561: type checkers use the package's own type hints.
    package_data={package_name: ['py.typed'], package_name + '.link': ['frames/*.yaml']},
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/config', glob('config/*.yaml') + glob('config/*.xml')),
        ('share/' + package_name + '/launch', glob('launch/*.launch.py')),
        ('share/' + package_name + '/urdf', glob('urdf/*.urdf')),
        ('share/' + package_name + '/rviz', glob('rviz/*.rviz')),
        ('share/' + package_name + '/security', glob('security/*.policy.xml')),
    ],
    # What the package imports (requirements.txt adds ROS 2 Jazzy from PyPI; package.xml
    # declares the same for rosdep).
    install_requires=['setuptools', 'numpy', 'pyserial', 'PyYAML', 'matplotlib', 'rosbags',
                      'lz4', 'backports.zstd; python_version < "3.14"', 'mujoco',
                      'gymnasium-robotics', 'eclipse-zenoh'],
    zip_safe=True,
    maintainer='kraft_master_driver maintainers',
    maintainer_email='maintainers@kraft-master-driver.org',
    description='ROS 2 driver for the Kraft Master force-reflecting hand controller',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'kraft_master_node = kraft_master_driver.nodes.commands:driver',
            'kraft_master_sim = kraft_master_driver.simulation.master.simulator:main',
            'kraft_master_slave_sim = kraft_master_driver.nodes.commands:slave_sim',
            'kraft_master_urdf = kraft_master_driver.tools.urdf_model:main',
            'kraft_master_report = kraft_master_driver.tools.report:main',
            'kraft_master_calibrate = kraft_master_driver.tools.calibrate:main',
            'kraft_master_demo = kraft_master_driver.tools.demo:main',
            'kraft_master_record = kraft_master_driver.tools.record:main',
            'kraft_master_ctl = kraft_master_driver.tools.ctl:main',
            'kraft_master_sniff = kraft_master_driver.tools.sniff:main',
            'kraft_master_link_emulator = kraft_master_driver.nodes.commands:link_emulator',
            'kraft_master_teleop = kraft_master_driver.nodes.commands:teleop',
            'kraft_master_arm_sim = kraft_master_driver.nodes.commands:arm_sim',
            'kraft_master_zenoh_link = kraft_master_driver.nodes.commands:zenoh_link',
        ],
    },
)

from setuptools import find_packages, setup

package_name = 'biped_sim'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'tests']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='Biped developers',
    maintainer_email='biped@example.com',
    description='Planar 7-link biped simulator (floating base, rigid contact, impacts), push disturbances and an MCAP recorder, as ROS 2 nodes.',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'simulator = biped_sim.graph.simulator_node:main',
            'disturbance = biped_sim.graph.disturbance_node:main',
            'recorder = biped_sim.graph.recorder_node:main',
            'bridge = biped_sim.live.bridge_node:main',
            'live_recorder = biped_sim.live.live_recorder:main',
        ],
    },
)

from setuptools import find_packages, setup

package_name = 'biped_model'

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
    description='The robot, owned by both sides (no ROS): description, gait family, Pinocchio models and their '
                'compiled twins, the settings reader. A robot lives in robots/<name>/.',
    license='Apache-2.0',
)

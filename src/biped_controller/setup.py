from setuptools import find_packages, setup

package_name = 'biped_controller'

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
    description='Gait controller of the planar biped: gait family q_d(p, tau), PIQP-based adaptation of p and tau under 17 constraints, as a ROS 2 node.',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'controller = biped_controller.graph.controller_node:main',
        ],
        # controllers shipped with the product that run through the controller interface like any plug-in
        # (docs/controllers.md): the DCM step layer above the whole-body QP (plugin/step_layer.py)
        'biped.controllers': [
            'dcm_wbc = biped_controller.plugin.step_layer:DcmWholeBody',
            # an ONNX policy file (option file=PATH) held over its policy period (docs/policies.md)
            'onnx_policy = biped_controller.policy.controller:OnnxPolicy',
        ],
        # the committed policies (policies/<name>/policy.onnx + policy.json), each a controller by its name
        'biped.controller_catalogs': [
            'policies = biped_controller.policy.catalog:registrations',
        ],
    },
)

from setuptools import setup

PACKAGE = 'arm_check_example'

setup(
    name=PACKAGE,
    version='0.1.0',
    packages=[PACKAGE],
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + PACKAGE]),
        ('share/' + PACKAGE, ['package.xml']),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='arm_sim developers',
    maintainer_email='arm-sim@example.com',
    description='Computed-torque control of the 2-R arm over topics, graded by arm-sim check.',
    license='Apache-2.0',
    entry_points={'console_scripts': ['controller = arm_check_example.controller:main']},
)

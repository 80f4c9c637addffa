"""ament_python package st_stereo: sub-pixel thermal stereo for two FLIR Lepton 2 cameras."""

from glob import glob

from setuptools import find_packages, setup

package_name = 'st_stereo'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/config', glob('config/*.yaml')),
        ('share/' + package_name + '/config/calibration', glob('config/calibration/*.yaml')),
        ('share/' + package_name + '/launch', glob('launch/*.launch.py')),
        ('share/' + package_name + '/data/textures', glob('data/textures/*')),
        ('share/' + package_name + '/data/recordings/office',
         [f for f in glob('data/recordings/office/*') if not f.endswith('bag')]),
        ('share/' + package_name + '/data/recordings/office/bag',
         glob('data/recordings/office/bag/*')),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='st_stereo developers',
    maintainer_email='st-stereo@example.invalid',
    description='ST: sub-pixel stereo matching of low-resolution thermal images, ROS 2 nodes '
                'for a ceiling rig of two FLIR Lepton 2 cameras.',
    license='Apache-2.0',
    tests_require=['pytest'],
    entry_points={
        'console_scripts': [
            'st-stereo = st_stereo.cli:main',
            'st-stereo-suite = st_stereo.tools.main_job:run_suite',
            'lepton_driver = st_stereo.nodes.driver_node:main',
            'rectifier = st_stereo.nodes.rectifier_node:main',
            'matcher = st_stereo.nodes.matcher_node:main',
            'people = st_stereo.nodes.people_node:main',
            'stereo_pipeline = st_stereo.nodes.pipeline:main',
            'bag_record = st_stereo.nodes.bags:record_main',
            'bag_play = st_stereo.nodes.bags:play_main',
            'st-stereo-latency = st_stereo.tools.latency_bench:main',
        ],
    },
)

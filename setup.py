import os
import shutil
import sys
from glob import glob

from setuptools import find_packages, setup
from setuptools.command.develop import develop as _develop
from setuptools.command.install import install as _install

package_name = 'zeroshot_calib_ros'


def _colcon_style_install(argv):
    """Return True when setup.py runs as `setup.py ... install|develop`.

    The ROS executable is called `node` (so that it can be started as
    `ros2 run zeroshot_calib_ros node`).  It must only ever be installed into
    the package-private directory lib/zeroshot_calib_ros/, never into a
    `bin/` directory on PATH: in a virtualenv's bin/ a script called `node`
    would shadow Node.js.

    * colcon's ament_python build runs setup.py directly, as
      `setup.py egg_info ... build ... install --install-scripts
      <prefix>/lib/zeroshot_calib_ros ...` or, with --symlink-install,
      `setup.py develop --editable ...`; the script directories come from
      setup.cfg ([install] install_scripts / [develop] script_dir).
    * pip (`pip install .`, `pip wheel .`, also editable installs through
      PEP 660) builds a wheel through the PEP 517 backend, which runs
      setup.py with `bdist_wheel`, `dist_info`, `egg_info` or
      `editable_wheel`, never `install` or `develop`, and a wheel's console
      scripts always land in bin/.  So `node` is declared only for the
      former.

    One more guard: inside a virtualenv setuptools ignores setup.cfg's
    install_scripts, so a bare `python setup.py install` there would put the
    scripts in the venv's bin/.  colcon always passes --install-scripts on
    the command line (for exactly that reason), so in a venv `install`
    counts only together with an explicit --install-scripts.
    (`develop` honours setup.cfg's script_dir even in a venv.)
    """
    args = argv[1:]
    if 'develop' in args:
        return True
    if 'install' in args:
        in_venv = sys.prefix != sys.base_prefix
        explicit_scripts_dir = any(
            a == '--install-scripts' or a.startswith('--install-scripts=')
            for a in args)
        return explicit_scripts_dir or not in_venv
    return False


def _direct_entry_script(path, module, function):
    """Rewrite setuptools' easy-install wrapper at ``path`` as pip writes console scripts: a
    plain import of ``module``. The easy-install wrapper first looks the entry point up in the
    installed metadata (importlib.metadata scans sys.path: 7 ms to 0.1 s of every `ros2 run`
    here, benchmarks/first_camera_info.py --imports) before the node's first line runs, and that
    start-up is what the first CameraInfo waits for (issue 14).
    The interpreter line stays the one setuptools wrote."""
    with open(path) as f:
        text = f.read()
    if 'EASY-INSTALL-ENTRY-SCRIPT' not in text:
        return
    shebang = text.splitlines()[0]
    with open(path, 'w') as f:
        f.write(f"""{shebang}
# console script of {package_name}: {module}:{function}, imported directly (as pip writes it)
import re
import sys

from {module} import {function}

if __name__ == '__main__':
    sys.argv[0] = re.sub(r'(-script\\.pyw?|\\.exe)?$', '', sys.argv[0])
    sys.exit({function}())
""")


def _finish_scripts(script_dir):
    """The console scripts in ``script_dir`` import their module directly, and, where
    ``script_dir`` is colcon's <prefix>/lib/zeroshot_calib_ros, ``<prefix>/bin/zeroshot-calib``.

    setup.cfg sends every script to lib/zeroshot_calib_ros/ (where `ros2 run` looks, and where
    `node` must stay); the CLI also belongs on PATH after `source install/setup.bash`. colcon
    puts <prefix>/bin on PATH when it exists, so the CLI's wrapper (same interpreter line) is
    copied there. Only `zeroshot-calib`: never `node` (it would shadow Node.js)."""
    for entry in console_scripts:
        name, target = (part.strip() for part in entry.split('='))
        module, function = target.split(':')
        path = os.path.join(script_dir, name)
        if os.path.isfile(path):
            _direct_entry_script(path, module, function)
    script = os.path.join(script_dir, 'zeroshot-calib')
    libdir = os.path.normpath(script_dir)
    if os.path.basename(libdir) == package_name and os.path.isfile(script):
        bindir = os.path.join(os.path.dirname(os.path.dirname(libdir)), 'bin')
        os.makedirs(bindir, exist_ok=True)
        shutil.copy2(script, os.path.join(bindir, 'zeroshot-calib'))


class install(_install):
    """colcon's install (`colcon build`): see _finish_scripts."""

    def run(self):
        super().run()
        _finish_scripts(self.install_scripts)


class develop(_develop):
    """colcon's `colcon build --symlink-install` (setup.py develop, scripts in setup.cfg's
    [develop] script_dir): the same as install, see _finish_scripts."""

    def run(self):
        super().run()
        if not self.uninstall:
            _finish_scripts(self.script_dir)


console_scripts = ['zeroshot-calib = zeroshot_calib_ros.cli:main']
if _colcon_style_install(sys.argv):
    console_scripts.append('node = zeroshot_calib_ros.ros.entry_point:main')

config_files = sorted(
    glob(os.path.join('config', '*.yaml'))
    + glob(os.path.join('config', '*.yml'))
    + glob(os.path.join('config', '*.xml')))
# share/<package>/launch/, where bringups include them from (FindPackageShare + 'launch')
launch_files = sorted(glob(os.path.join('launch', '*.launch.py')))

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'test.*']),
    # camera presets (zeroshot-calib presets) and the lens-law prior (core/zeroshot/lens_prior.py)
    package_data={package_name: ['data/*.csv']},
    data_files=[
        ('share/ament_index/resource_index/packages',
            ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/config', config_files),
        ('share/' + package_name + '/launch', launch_files),
    ],
    install_requires=[
        'numpy',
        'scipy',
        'opencv-python-headless>=4.6,<6',
        'pyyaml',
    ],
    zip_safe=True,
    maintainer='Zeroshot Calib Maintainers',
    maintainer_email='maintainers@zeroshot-calib.dev',
    description=(
        'Zero-shot calibration of wide-angle and fisheye cameras from their '
        'spec-sheet field of view (J.-Y. Lee, CVPR 2021): CameraInfo '
        'publisher and rectifier.'),
    license='Apache-2.0',
    python_requires='>=3.10',
    entry_points={
        'console_scripts': console_scripts,
    },
    cmdclass={'install': install, 'develop': develop},
)

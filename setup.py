"""One import root, `fake_marlin`, over the top-level folders emulator/, host/ and wire/.

setuptools' package-dir mapping installs each folder under its name in fake_marlin; the
subpackages are found in each folder, so a new one needs no entry here.
"""

from setuptools import find_packages, setup

PARTS = ("emulator", "host", "wire")

package_dir = {"fake_marlin": "fake_marlin"}
packages = ["fake_marlin"]
for part in PARTS:
    package_dir[f"fake_marlin.{part}"] = part
    packages += [f"fake_marlin.{part}"] + [f"fake_marlin.{part}.{sub}" for sub in find_packages(part)]

setup(package_dir=package_dir, packages=packages, package_data={"fake_marlin": ["py.typed"]})

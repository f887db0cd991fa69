#!/usr/bin/env bash
# System packages volterra needs to build and test (Debian/Ubuntu). Installs only what is
# missing; uses sudo when not root.
#   libcharls-dev   CharLS, the JPEG-LS decoder dicom-pixeldata links
#   cmake           charls-sys 2.4 builds its bundled CharLS with CMake, turbojpeg-sys its
#                   bundled libjpeg-turbo 3 (12-bit JPEG) (not every machine has it: a
#                   fresh one here did not)
#   python3-venv    the venv for the reference readers (tests only)
#   mesa-vulkan-drivers, libvulkan1  lavapipe, the software Vulkan adapter the terrain
#                   ray-caster's tests run on where there is no GPU
#   xvfb, xauth, libx11-6 libxcursor1 libxrandr2 libxi6 libxkbcommon-x11-0
#                   the viewer's window (winit loads the X libraries at run time); the
#                   test of a real window runs it under Xvfb
#   slurmctld, slurmd, slurm-client, munge
#                   a single-node Slurm cluster the tests start (tests/slurm.rs) to run
#                   `volterra slurm`'s job arrays for real
#   ffmpeg          `volterra movie` (frames to MP4/GIF)
#   gdal-bin        gdaldem and gdalinfo, the reference for `volterra dem` (tests only)
#   python3-gdal    GDAL's Cloud-Optimised GeoTIFF validator, for `volterra dem -of COG` (tests only)
set -euo pipefail
need=()
for pkg in libcharls-dev cmake python3-venv mesa-vulkan-drivers libvulkan1 xvfb xauth libx11-6 libxcursor1 libxrandr2 libxi6 libxkbcommon-x11-0 slurmctld slurmd slurm-client munge ffmpeg gdal-bin python3-gdal; do
    dpkg -s "$pkg" >/dev/null 2>&1 || need+=("$pkg")
done
if [ ${#need[@]} -gt 0 ]; then
    SUDO=""
    [ "$(id -u)" -eq 0 ] || SUDO="sudo"
    $SUDO apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq "${need[@]}" >/dev/null
fi

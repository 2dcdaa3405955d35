"""Data input/output and data-set loaders (numpy/OpenCV only, no JAX)."""

from stereojax.data.datasets import (DATASETS, DEFAULT_DATA, Calibration, StereoSample,
                                     list_kitti2012, list_kitti2015, list_middlebury,
                                     load_builtin_sample, load_dataset, load_kitti2012,
                                     load_kitti2015, load_middlebury, load_pair, search_range)
from stereojax.data.io import (atomic_output, colorize_disparity, error_map, read_image,
                               read_kitti_disparity, read_pfm, write_color_disparity,
                               write_error_map, write_kitti_disparity, write_pfm, write_png)

__all__ = [
    "DATASETS", "DEFAULT_DATA", "Calibration", "StereoSample", "load_pair", "list_kitti2015", "load_kitti2015",
    "list_kitti2012", "load_kitti2012", "list_middlebury", "load_middlebury", "load_builtin_sample",
    "load_dataset", "search_range", "atomic_output", "read_image", "read_pfm", "write_pfm", "read_kitti_disparity",
    "write_kitti_disparity", "colorize_disparity", "write_color_disparity", "error_map",
    "write_error_map", "write_png",
]

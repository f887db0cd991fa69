#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| volterra_fuzz::run("vtk_image", data));

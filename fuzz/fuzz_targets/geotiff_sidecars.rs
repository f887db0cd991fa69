#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| volterra_fuzz::run("geotiff_sidecars", data));

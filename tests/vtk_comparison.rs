//! Our renderers and VTK's vtkFixedPointVolumeRayCastMapper (images made by
//! tests/reference/vtk_volume.py from the same scene files) against the reference ray
//! caster, on the real aneurism scan: axis-aligned, oblique, and exactly at the 45° switch
//! of principal axis.

mod common;

use common::repo_path;
use volterra::compare::{rgba_pixels as rgba, rgba_rel_rmse as rel_rmse};
use volterra::render::{self, Frame};
use volterra::scene::Scene;

fn render_with(scene: &Scene, renderer: &str) -> Frame {
    let path = scene.source.clone();
    let s = Scene::load(&path, &[format!("node.aneurism.renderer={renderer}")]).unwrap();
    render::render_scene(&s, None).unwrap()
}

#[test]
fn shear_warp_is_closer_to_the_reference_than_vtk_at_every_view() {
    if common::shared_data().is_none() {
        return;
    }
    for view in ["axis", "oblique", "switch45"] {
        let scene = Scene::load(&repo_path(&format!("tests/reference/scenes/aneurism_{view}.toml")), &[]).unwrap();
        let vtk = rgba(&volterra_formats::exr_io::read_exr(&repo_path(&format!("tests/reference/data/vtk_aneurism_{view}.exr"))).unwrap());
        let reference = render_with(&scene, "reference");
        let ours = render_with(&scene, "shear-warp");
        let e_vtk = rel_rmse(&vtk, &reference.rgba);
        let e_ours = rel_rmse(&ours.rgba, &reference.rgba);
        eprintln!("{view}: VTK fixed-point {:.2} %, shear-warp {:.2} % from the reference", 100.0 * e_vtk, 100.0 * e_ours);
        // VTK agrees with the reference to about its known sample-distance-1 error (the
        // issue's ~12 %): camera, transfer function and compositing conventions match. A
        // flipped axis or a wrong opacity correction gives several times that.
        assert!(e_vtk < 0.15, "{view}: VTK is {e_vtk} from the reference — conventions differ?");
        assert!(e_ours < 0.5 * e_vtk, "{view}: shear-warp {e_ours} vs VTK {e_vtk}");
    }
}

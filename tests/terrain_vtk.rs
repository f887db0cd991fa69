//! The terrain renderers against VTK: tests/reference/vtk_terrain.py renders the same
//! heightfield (Puget Sound, ../shared/data) as a triangle mesh with the same camera and
//! stores the depth along each pixel's ray. Our f64 reference intersecting the same two
//! triangles per cell must agree with VTK to its z-buffer's precision — proof that camera
//! and georeferencing conventions match — and the GPU's bilinear patches may differ from
//! VTK only as much as bilinear patches differ from triangles.

mod common;

use glam::DMat4;
use volterra::render::terrain::grid::TerrainGrid;
use volterra::render::terrain::reference::{render_surface, Surface};
use volterra::render::terrain::shading::{sun_lights, Shading};
use volterra::render::terrain::{self, depth_agreement, Settings, TerrainInput};
use volterra::render::Frame;
use volterra::scene::Scene;

fn depth_frame(depth: Vec<f32>, w: usize, h: usize) -> Frame {
    let mut f = Frame::empty(w, h);
    f.depth = depth;
    f
}

#[test]
fn puget_sound_depth_matches_vtk_triangle_mesh() {
    if common::shared_data().is_none() {
        return;
    }
    for name in ["puget_fly", "puget_low"] {
        let scene = Scene::load(&common::repo_path(&format!("tests/reference/terrain_scenes/{name}.toml")), &[]).unwrap();
        let hf = scene.heightfield(0).unwrap();
        let (w, h) = (scene.file.image.width, scene.file.image.height);
        let rays = scene.file.camera.rays(w, h);
        let vtk = volterra_formats::exr_io::read_exr(
            &common::repo_path(&format!("tests/reference/data/vtk_terrain_{name}.exr")),
            &Default::default(),
        )
        .unwrap();
        let mut vtk = depth_frame(vtk.channel("Z").unwrap().to_vec(), w, h);

        let grid = TerrainGrid::new(&hf, DMat4::IDENTITY).unwrap();
        let shading = Shading {
            lights: sun_lights(&[]).unwrap(),
            ambient: 0.25,
            shadows: false,
            smooth: true,
            rays_per_side: 1,
            colormap: volterra::colormap::Colormap::Hypsometric,
            colour_range: None,
        };
        let triangles = render_surface(&grid, None, &rays, &shading, Surface::Triangles).unwrap();
        let mut bilinear = render_surface(&grid, None, &rays, &shading, Surface::Bilinear).unwrap();
        // Our terrain is a solid with walls at its edges; VTK's mesh is a sheet. Pixels
        // that see a wall are left out of every comparison.
        let mut triangles = triangles;
        let walls: Vec<bool> = bilinear.extra.iter().find(|e| e.0 == "wall").unwrap().1.iter().map(|&v| v > 0.5).collect();
        let tri_walls: Vec<bool> = triangles.extra.iter().find(|e| e.0 == "wall").unwrap().1.iter().map(|&v| v > 0.5).collect();
        let excluded: Vec<bool> = walls.iter().zip(&tri_walls).map(|(a, b)| *a || *b).collect();
        for f in [&mut vtk, &mut triangles, &mut bilinear] {
            for (d, &x) in f.depth.iter_mut().zip(&excluded) {
                if x {
                    *d = f32::INFINITY;
                }
            }
        }
        println!("{name}: {} of {} pixels see the terrain's walls and are left out", excluded.iter().filter(|&&x| x).count(), w * h);
        let tri_vs_vtk = depth_agreement(&triangles, &vtk);
        let bil_vs_tri = depth_agreement(&bilinear, &triangles);
        println!("{name}: our triangles vs VTK: {tri_vs_vtk:?}");
        println!("{name}: bilinear patches vs triangles (both ours, f64): {bil_vs_tri:?}");
        let pixels = (w * h) as f64;
        // Conventions: same camera, same georeferencing, same surface → VTK's 24-bit depth
        // buffer is the only difference.
        assert!(tri_vs_vtk.median_rel < 1e-4, "{name}: median relative depth difference {}", tri_vs_vtk.median_rel);
        assert!((tri_vs_vtk.mismatched_off_silhouette as f64) < 1e-3 * pixels, "{name}: {tri_vs_vtk:?}");

        if common::gpu().is_none() {
            continue;
        }
        let input = TerrainInput { heightfield: &hf, texture: None, node_to_world: DMat4::IDENTITY, lights: &[] };
        let mut gpu = terrain::render(&input, &rays, &Settings::default()).unwrap();
        for (d, &x) in gpu.depth.iter_mut().zip(&excluded) {
            if x {
                *d = f32::INFINITY;
            }
        }
        let gpu_vs_vtk = depth_agreement(&gpu, &vtk);
        println!("{name}: GPU (bilinear) vs VTK: {gpu_vs_vtk:?}");
        // The GPU sees bilinear patches, VTK triangles: they may differ by what the two
        // surfaces differ by (plus VTK's depth precision), no more.
        assert!(gpu_vs_vtk.median_rel <= bil_vs_tri.median_rel + 2.0 * tri_vs_vtk.median_rel + 1e-6, "{name}: {gpu_vs_vtk:?}");
        assert!(gpu_vs_vtk.mismatched_off_silhouette <= bil_vs_tri.mismatched_off_silhouette + tri_vs_vtk.mismatched_off_silhouette + 2);
    }
}

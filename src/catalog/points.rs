//! The settings of `points` (`render::points`).

use super::{NodeKind, NodeSettings, RendererDecl};
use crate::colormap::Colormap;
use crate::settings::{Bounds, Control, SettingError, Widget};

crate::setting_choice! {
    /// How each particle is drawn.
    pub enum PointStyle {
        /// An opaque sphere of the particle's radius, shaded by a headlight; exact
        /// ray-sphere depth.
        Spheres = "spheres",
        /// A translucent Gaussian blob (σ = radius / 3, cut at the radius), unshaded, blended
        /// order-independently: the look of a density field rather than of balls.
        Splats = "splats",
    }
}

crate::setting_choice! {
    /// Where a particle's radius comes from when `radius` is 0.
    pub enum RadiusOf {
        /// Spheres: half the distance to the particle's nearest neighbour, at most its h (no
        /// two spheres overlap: a dense core shows the particles it holds, not a blob of
        /// balls hiding it); splats, which are meant to blend: h.
        Auto = "auto",
        /// Half the distance to the nearest neighbour (at most h), for splats too.
        Spacing = "spacing",
        /// Each particle's smoothing length h (VTK's and pyvista's scale array h).
        H = "h",
    }
}

crate::declare_settings! {
    pub struct Settings {
        /// How each particle is drawn.
        pub style: PointStyle = PointStyle::Spheres, viewer = Control { label: "Style", widget: Widget::ByType };
        /// Sphere radius in the particles' length unit; 0: each particle's own (`radius_of`).
        pub radius: f64 = 0.0, range = Bounds::above(0.0), zero = "auto: each particle's own, by radius_of",
            viewer = Control { label: "Radius (0: auto)", widget: Widget::Drag { lo: 0.0, hi: 1e30, speed: 0.001 } };
        /// Where each particle's radius comes from when `radius` is 0.
        pub radius_of: RadiusOf = RadiusOf::Auto, viewer = Control { label: "Radius from", widget: Widget::ByType };
        /// The colour map for the node's `color_by` array.
        pub colormap: Colormap = Colormap::Viridis, viewer = Control { label: "Colour map", widget: Widget::ByType };
        /// Splats only: each splat's opacity at its centre (falling off as its Gaussian).
        pub opacity: f64 = 0.3, range = Bounds::open_closed(0.0, 1.0),
            viewer = Control { label: "Opacity", widget: Widget::Slider { lo: 0.01, hi: 1.0, step: 0.01 } };
    }
}

impl Settings {
    /// Whether each particle's radius is half its nearest neighbour's distance
    /// (`spacing_radii`): `radius` 0 and `radius_of` spacing, or auto for spheres.
    pub fn radius_by_spacing(&self) -> bool {
        self.radius == 0.0
            && match self.radius_of {
                RadiusOf::Auto => self.style == PointStyle::Spheres,
                RadiusOf::Spacing => true,
                RadiusOf::H => false,
            }
    }
}

/// The settings a node's table gives; `opacity` is refused unless the style is splats
/// (spheres are opaque), before anything is drawn.
fn parse(t: &toml::Table) -> Result<NodeSettings, SettingError> {
    let s = Settings::from_table(t)?;
    if s.style != PointStyle::Splats && t.contains_key("opacity") {
        return Err(SettingError { key: "opacity".into(), message: "applies to style = \"splats\" only (spheres are opaque)".into() });
    }
    Ok(NodeSettings::Points(s))
}

pub const RENDERER: RendererDecl = RendererDecl {
    name: "points",
    kind: NodeKind::Particles,
    doc: "Every particle as a sphere or a Gaussian splat on the GPU (wgpu), coloured by a point \
          array (the node's `color_by`, default density) through a colour map over \
          `color_range` (default: the data's range). Spheres: shaded by a headlight, exact \
          ray-sphere depth. Splats: blended order-independently, depth where a ray passes \
          within σ of a centre. Composited with the other nodes by depth.",
    reference: false,
    settings: Settings::DECLS,
    heights_held: None,
    parse,
};

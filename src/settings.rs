//! Renderer settings, declared once. A renderer writes its `Settings` struct through
//! [`declare_settings!`]: that one declaration gives the struct, its defaults and a table
//! of [`SettingDecl`]s (key, type, default, unit, range, doc, viewer control, preview
//! value). The scene loader checks a node's `settings` table against it (an unknown key,
//! a wrong type or an out-of-range value is an error at load, before any data is read),
//! and the viewer, the benches and docs/scene-format.md read the same table.
//! Choice settings are enums written through [`setting_choice!`].

use std::fmt;

/// The kind of value a setting holds.
#[derive(Debug, Clone, Copy)]
pub enum SettingType {
    Float,
    Integer,
    Bool,
    /// One of a fixed list of names.
    Choice(&'static [Choice]),
}

impl SettingType {
    pub fn describe(&self) -> String {
        match self {
            SettingType::Float => "number".into(),
            SettingType::Integer => "integer".into(),
            SettingType::Bool => "boolean".into(),
            SettingType::Choice(c) => c.iter().map(|c| format!("\"{}\"", c.name)).collect::<Vec<_>>().join(" | "),
        }
    }
}

/// One name a choice setting accepts.
#[derive(Debug, Clone, Copy)]
pub struct Choice {
    pub name: &'static str,
    pub doc: &'static str,
}

/// A setting's value once checked against its declaration.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Value {
    Float(f64),
    Integer(i64),
    Bool(bool),
    Choice(&'static str),
}

impl Value {
    pub fn to_toml(self) -> toml::Value {
        match self {
            Value::Float(x) => toml::Value::Float(x),
            Value::Integer(i) => toml::Value::Integer(i),
            Value::Bool(b) => toml::Value::Boolean(b),
            Value::Choice(c) => toml::Value::String(c.into()),
        }
    }
    /// The value as a number (integers and floats), for ranges and sliders.
    pub fn as_f64(self) -> Option<f64> {
        match self {
            Value::Float(x) => Some(x),
            Value::Integer(i) => Some(i as f64),
            _ => None,
        }
    }
}

impl fmt::Display for Value {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Value::Float(x) => write!(f, "{x}"),
            Value::Integer(i) => write!(f, "{i}"),
            Value::Bool(b) => write!(f, "{b}"),
            Value::Choice(c) => write!(f, "\"{c}\""),
        }
    }
}

/// An interval of allowed numbers; either end open or closed.
#[derive(Debug, Clone, Copy)]
pub struct Bounds {
    pub lo: f64,
    pub lo_open: bool,
    pub hi: f64,
    pub hi_open: bool,
}

impl Bounds {
    /// lo ≤ x ≤ hi.
    pub const fn closed(lo: f64, hi: f64) -> Bounds {
        Bounds { lo, lo_open: false, hi, hi_open: false }
    }
    /// lo < x ≤ hi.
    pub const fn open_closed(lo: f64, hi: f64) -> Bounds {
        Bounds { lo, lo_open: true, hi, hi_open: false }
    }
    /// x ≥ lo.
    pub const fn at_least(lo: f64) -> Bounds {
        Bounds { lo, lo_open: false, hi: f64::INFINITY, hi_open: true }
    }
    /// x > lo.
    pub const fn above(lo: f64) -> Bounds {
        Bounds { lo, lo_open: true, hi: f64::INFINITY, hi_open: true }
    }
    pub fn contains(&self, x: f64) -> bool {
        let lo = if self.lo_open { x > self.lo } else { x >= self.lo };
        let hi = if self.hi_open { x < self.hi } else { x <= self.hi };
        lo && hi
    }
}

impl fmt::Display for Bounds {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match (self.lo_open, self.hi.is_infinite()) {
            (false, true) => write!(f, "≥ {}", self.lo),
            (true, true) => write!(f, "> {}", self.lo),
            _ => write!(f, "{}{}, {}{}", if self.lo_open { "(" } else { "[" }, self.lo, self.hi, if self.hi_open { ")" } else { "]" }),
        }
    }
}

/// How the viewer shows a setting it offers (booleans are check boxes, choices combo
/// boxes; numbers need one of these).
#[derive(Debug, Clone, Copy)]
pub enum Widget {
    /// A check box or a combo box, from the setting's type.
    ByType,
    Slider {
        lo: f64,
        hi: f64,
        step: f64,
    },
    Drag {
        lo: f64,
        hi: f64,
        speed: f64,
    },
}

/// A setting the viewer offers, with its label.
#[derive(Debug, Clone, Copy)]
pub struct Control {
    pub label: &'static str,
    pub widget: Widget,
}

/// The cheaper value the viewer's quick previews use while the camera moves.
#[derive(Debug, Clone, Copy)]
pub enum Preview {
    /// At most this (a zero that means "auto" counts as more).
    AtMost(f64),
    /// At least this.
    AtLeast(f64),
}

/// One setting of one renderer.
#[derive(Debug, Clone, Copy)]
pub struct SettingDecl {
    pub key: &'static str,
    pub ty: SettingType,
    pub default: fn() -> Value,
    /// Unit of a number ("" for none).
    pub unit: &'static str,
    pub range: Option<Bounds>,
    /// What the Rust type holds (unsigned integers: 0 up to its maximum).
    pub natural: Option<Bounds>,
    /// What 0 means when it is not a value in the range ("auto: …").
    pub zero: Option<&'static str>,
    /// The doc comment of the struct field.
    pub doc: &'static str,
    /// A quality knob (step, ratio, termination, photons) rather than part of what the
    /// picture shows (shadows, ambient light): a view redrawn by the kind's reference
    /// renderer drops the quality knobs and keeps the rest.
    pub quality: bool,
    pub viewer: Option<Control>,
    pub preview: Option<Preview>,
}

impl SettingDecl {
    /// Checks a TOML value against the declaration.
    pub fn check(&self, v: &toml::Value) -> Result<Value, String> {
        let value = match (self.ty, v) {
            (SettingType::Float, toml::Value::Float(x)) => Value::Float(*x),
            // TOML writes 2 for 2.0; serde read it as a number too.
            (SettingType::Float, toml::Value::Integer(i)) => Value::Float(*i as f64),
            (SettingType::Integer, toml::Value::Integer(i)) => Value::Integer(*i),
            (SettingType::Bool, toml::Value::Boolean(b)) => Value::Bool(*b),
            (SettingType::Choice(choices), toml::Value::String(s)) => match choices.iter().find(|c| c.name == s) {
                Some(c) => Value::Choice(c.name),
                None => return Err(format!("\"{s}\" is not one of {}", self.ty.describe())),
            },
            (ty, other) => return Err(format!("expected {}, found {} {other}", ty.describe(), other.type_str())),
        };
        if let Some(x) = value.as_f64() {
            let zero_ok = x == 0.0 && self.zero.is_some();
            for b in [self.range, self.natural].into_iter().flatten() {
                if !(zero_ok || x.is_finite() && b.contains(x)) {
                    let zero = self.zero.map(|z| format!(" or 0 ({z})")).unwrap_or_default();
                    return Err(format!("{value} is out of range: must be {b}{zero}"));
                }
            }
        }
        Ok(value)
    }

    /// The first sentence of the doc, for tables and tooltips.
    pub fn summary(&self) -> String {
        summary(self.doc)
    }
}

/// The first sentence of a doc comment, on one line (a sentence ends at a full stop
/// followed by a capital letter, so "Fig. 6b" does not end one).
pub fn summary(doc: &str) -> String {
    let text = doc.split_whitespace().collect::<Vec<_>>().join(" ");
    let end = text.match_indices(". ").find(|(i, _)| text[i + 2..].starts_with(|c: char| c.is_uppercase()));
    match end {
        Some((i, _)) => text[..=i].to_string(),
        None => text,
    }
}

/// What a setting failed on: the key and a message; the scene adds the node and line.
#[derive(Debug, Clone, PartialEq)]
pub struct SettingError {
    pub key: String,
    pub message: String,
}

impl fmt::Display for SettingError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "setting '{}': {}", self.key, self.message)
    }
}

/// A Rust type a setting can have.
pub trait SettingValue: Sized {
    const TYPE: SettingType;
    /// The range every value of the type must be in (integers: what the type holds).
    const NATURAL: Option<Bounds> = None;
    fn to_value(&self) -> Value;
    /// From a value that passed [`SettingDecl::check`] for this type.
    fn from_value(v: Value) -> Self;
}

impl SettingValue for f64 {
    const TYPE: SettingType = SettingType::Float;
    fn to_value(&self) -> Value {
        Value::Float(*self)
    }
    fn from_value(v: Value) -> f64 {
        v.as_f64().expect("checked")
    }
}

impl SettingValue for bool {
    const TYPE: SettingType = SettingType::Bool;
    fn to_value(&self) -> Value {
        Value::Bool(*self)
    }
    fn from_value(v: Value) -> bool {
        matches!(v, Value::Bool(true))
    }
}

macro_rules! unsigned_setting {
    ($($t:ty),*) => {$(
        impl SettingValue for $t {
            const TYPE: SettingType = SettingType::Integer;
            const NATURAL: Option<Bounds> = Some(Bounds::closed(0.0, if (<$t>::MAX as u128) < i64::MAX as u128 { <$t>::MAX as f64 } else { i64::MAX as f64 }));
            fn to_value(&self) -> Value {
                Value::Integer(*self as i64)
            }
            fn from_value(v: Value) -> $t {
                match v {
                    Value::Integer(i) => i as $t,
                    _ => unreachable!("checked"),
                }
            }
        }
    )*};
}
unsigned_setting!(usize, u32, u64);

/// Declares a renderer's settings struct: each field with its doc comment, type and
/// default, and optionally `unit = "…"`, `range = Bounds::…`, `zero = "…"` (what 0
/// means), `quality = true`, `viewer = Control {…}` and `preview = Preview::…`, in that
/// order.
/// Generates the struct, `Default`, `Settings::DECLS` and `Settings::from_table`.
#[macro_export]
macro_rules! declare_settings {
    (
        $(#[$meta:meta])*
        pub struct $name:ident {
            $(
                $(#[doc = $doc:literal])+
                pub $field:ident : $ty:ty = $default:expr
                    $(, unit = $unit:literal)?
                    $(, range = $range:expr)?
                    $(, zero = $zero:literal)?
                    $(, quality = $quality:literal)?
                    $(, viewer = $viewer:expr)?
                    $(, preview = $preview:expr)?
                ;
            )*
        }
    ) => {
        $(#[$meta])*
        #[derive(Debug, Clone, PartialEq)]
        pub struct $name {
            $( $(#[doc = $doc])+ pub $field: $ty, )*
        }

        impl Default for $name {
            fn default() -> Self {
                $name { $( $field: $default, )* }
            }
        }

        impl $name {
            /// Every setting, in declaration order.
            pub const DECLS: &'static [$crate::settings::SettingDecl] = &[
                $( $crate::settings::SettingDecl {
                    key: stringify!($field),
                    ty: <$ty as $crate::settings::SettingValue>::TYPE,
                    default: || <$ty as $crate::settings::SettingValue>::to_value(&$default),
                    unit: $crate::declare_settings!(@or "" $($unit)?),
                    range: $crate::declare_settings!(@some $($range)?),
                    natural: <$ty as $crate::settings::SettingValue>::NATURAL,
                    zero: $crate::declare_settings!(@some $($zero)?),
                    doc: concat!($($doc, "\n"),+),
                    quality: $crate::declare_settings!(@or false $($quality)?),
                    viewer: $crate::declare_settings!(@some $($viewer)?),
                    preview: $crate::declare_settings!(@some $($preview)?),
                }, )*
            ];

            /// The settings a node's table gives; unknown keys, wrong types and values
            /// out of range are errors.
            pub fn from_table(table: &toml::Table) -> Result<Self, $crate::settings::SettingError> {
                let mut s = Self::default();
                for (key, raw) in table {
                    let decl = $crate::settings::find(Self::DECLS, key)?;
                    let v = decl.check(raw).map_err(|message| $crate::settings::SettingError { key: key.clone(), message })?;
                    match key.as_str() {
                        $( stringify!($field) => s.$field = <$ty as $crate::settings::SettingValue>::from_value(v), )*
                        _ => unreachable!("found above"),
                    }
                }
                Ok(s)
            }

            /// Checks every field against its declaration (for settings built in code).
            pub fn validate(&self) -> Result<(), $crate::settings::SettingError> {
                $( {
                    let key = stringify!($field);
                    let v = <$ty as $crate::settings::SettingValue>::to_value(&self.$field);
                    $crate::settings::find(Self::DECLS, key)?
                        .check(&v.to_toml())
                        .map_err(|message| $crate::settings::SettingError { key: key.into(), message })?;
                } )*
                Ok(())
            }
        }
    };
    (@or $d:literal) => { $d };
    (@or $d:literal $v:literal) => { $v };
    (@some) => { None };
    (@some $v:expr) => { Some($v) };
}

/// Declares a choice setting's enum: each variant with its doc and the name scene files
/// use. Generates the enum, `NAMES`-style `CHOICES`, `name()` and [`SettingValue`].
#[macro_export]
macro_rules! setting_choice {
    (
        $(#[$meta:meta])*
        pub enum $name:ident {
            $( $(#[doc = $doc:literal])+ $variant:ident = $text:literal, )*
        }
    ) => {
        $(#[$meta])*
        #[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
        pub enum $name {
            $( $(#[doc = $doc])+ $variant, )*
        }

        impl $name {
            pub const CHOICES: &'static [$crate::settings::Choice] =
                &[ $( $crate::settings::Choice { name: $text, doc: concat!($($doc, "\n"),+) }, )* ];
            pub const ALL: &'static [$name] = &[ $( $name::$variant, )* ];
            /// The name scene files use.
            pub fn name(self) -> &'static str {
                match self { $( $name::$variant => $text, )* }
            }
            /// The choice a scene file names `name`, if any.
            #[allow(dead_code)]
            pub fn from_name(name: &str) -> Option<$name> {
                Self::ALL.iter().copied().find(|c| c.name() == name)
            }
        }

        impl $crate::settings::SettingValue for $name {
            const TYPE: $crate::settings::SettingType = $crate::settings::SettingType::Choice(Self::CHOICES);
            fn to_value(&self) -> $crate::settings::Value {
                $crate::settings::Value::Choice(self.name())
            }
            fn from_value(v: $crate::settings::Value) -> Self {
                match v {
                    $( $crate::settings::Value::Choice($text) => $name::$variant, )*
                    _ => unreachable!("checked"),
                }
            }
        }
    };
}

/// The declaration of `key`, or an error listing the known keys.
pub fn find<'a>(decls: &'a [SettingDecl], key: &str) -> Result<&'a SettingDecl, SettingError> {
    decls.iter().find(|d| d.key == key).ok_or_else(|| {
        let known: Vec<&str> = decls.iter().map(|d| d.key).collect();
        let message = if known.is_empty() {
            "unknown: this renderer has no settings".to_string()
        } else {
            format!("unknown (known: {})", known.join(", "))
        };
        SettingError { key: key.to_string(), message }
    })
}

/// The value `table` gives `decl` (its default when absent or not valid).
pub fn current(decl: &SettingDecl, table: &toml::Table) -> Value {
    table.get(decl.key).and_then(|v| decl.check(v).ok()).unwrap_or_else(decl.default)
}

/// `table` with the cheaper preview values of `decls` applied: only settings the table
/// does not already make cheaper are touched.
pub fn apply_preview(decls: &[SettingDecl], table: &mut toml::Table) {
    for d in decls {
        let (Some(rule), Some(x)) = (d.preview, current(d, table).as_f64()) else { continue };
        let auto = x == 0.0 && d.zero.is_some();
        let target = match rule {
            Preview::AtMost(m) if auto || x > m => m,
            Preview::AtLeast(m) if x < m => m,
            _ => continue,
        };
        let v = match d.ty {
            SettingType::Integer => Value::Integer(target as i64),
            _ => Value::Float(target),
        };
        table.insert(d.key.to_string(), v.to_toml());
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    crate::setting_choice! {
        /// A test choice.
        pub enum Mode {
            /// The first.
            Fast = "fast",
            /// The second.
            Exact = "exact",
        }
    }

    crate::declare_settings! {
        pub struct Demo {
            /// A ratio. Zero picks one.
            pub ratio: f64 = 0.0, unit = "px", range = Bounds::open_closed(0.0, 4.0), zero = "auto: chosen", quality = true,
                preview = Preview::AtMost(1.0);
            /// A count.
            pub count: u32 = 3, range = Bounds::at_least(1.0), preview = Preview::AtLeast(5.0);
            /// A switch.
            pub on: bool = true;
            /// A mode.
            pub mode: Mode = Mode::Exact;
        }
    }

    fn table(text: &str) -> toml::Table {
        toml::from_str(text).unwrap()
    }

    #[test]
    fn a_table_gives_typed_settings_and_every_bad_value_is_named() {
        let s = Demo::from_table(&table("ratio = 2\ncount = 7\non = false\nmode = \"fast\"")).unwrap();
        assert_eq!(s, Demo { ratio: 2.0, count: 7, on: false, mode: Mode::Fast });
        assert_eq!(Demo::from_table(&toml::Table::new()).unwrap(), Demo::default());
        let err = |text: &str| Demo::from_table(&table(text)).unwrap_err();
        assert_eq!(err("rate = 1").message, "unknown (known: ratio, count, on, mode)");
        assert_eq!(err("ratio = 4.5").message, "4.5 is out of range: must be (0, 4] or 0 (auto: chosen)");
        assert_eq!(err("ratio = -1").message, "-1 is out of range: must be (0, 4] or 0 (auto: chosen)");
        assert_eq!(err("ratio = nan").key, "ratio");
        assert_eq!(err("count = 0").message, "0 is out of range: must be ≥ 1");
        // What a u32 holds bounds it even where the declared range does not.
        assert!(err("count = 5000000000").message.contains("out of range"));
        assert_eq!(err("count = 2.5").message, "expected integer, found float 2.5");
        assert_eq!(err("on = 1").message, "expected boolean, found integer 1");
        assert_eq!(err("mode = \"slow\"").message, "\"slow\" is not one of \"fast\" | \"exact\"");
        assert!(Demo::from_table(&table("ratio = 0")).is_ok(), "0 means auto");
    }

    #[test]
    fn declarations_hold_defaults_docs_and_checks_for_settings_built_in_code() {
        let d = &Demo::DECLS[0];
        assert_eq!((d.key, d.unit, (d.default)()), ("ratio", "px", Value::Float(0.0)));
        assert_eq!(d.summary(), "A ratio.");
        assert_eq!((Demo::DECLS[3].default)(), Value::Choice("exact"));
        assert_eq!(Mode::CHOICES.iter().map(|c| c.name).collect::<Vec<_>>(), ["fast", "exact"]);
        assert_eq!(Mode::ALL.iter().map(|m| m.name()).collect::<Vec<_>>(), ["fast", "exact"]);
        assert!(Demo::default().validate().is_ok());
        let e = Demo { count: 0, ..Default::default() }.validate().unwrap_err();
        assert_eq!(e.key, "count");
    }

    #[test]
    fn previews_only_make_settings_cheaper() {
        let mut t = toml::Table::new();
        apply_preview(Demo::DECLS, &mut t);
        // 0 (auto) counts as more than 1; the count's default 3 is raised to 5.
        assert_eq!(t, table("ratio = 1.0\ncount = 5"));
        let mut t = table("ratio = 0.5\ncount = 9");
        apply_preview(Demo::DECLS, &mut t);
        assert_eq!(t, table("ratio = 0.5\ncount = 9"));
    }

    #[test]
    fn summaries_end_at_a_sentence_not_at_an_abbreviation() {
        assert_eq!(summary("One lookup per run (paper Fig. 6b). More\n text."), "One lookup per run (paper Fig. 6b).");
        assert_eq!(summary("No full stop"), "No full stop");
    }
}

//! Geometry variants: other readings of the letter's words than the spec's (`GEOMETRY.md`), as
//! first-class, combinable options of a design. The formulas are documented in
//! `studies/letter-calibration/VARIANTS.md`.
//!
//! A variant is three independent choices; the default of each is the spec's:
//!
//! | choice | spec (default) | alternatives |
//! |---|---|---|
//! | [`SectionReading`]: how r maps onto the six-arc family | `triangle` (lobe chords on the inscribed triangle) | `tips-on-r` (lobe tips on R, d = R − r; GEOMETRY.md §8 (A)), `midpoint-centres` (lobe centres on the triangle's edge midpoints, d = R/2) |
//! | [`OffsetSide`]: which surface is designed | inward (the designed surface is the outer surface) | `outward` (the designed surface is the cavity) |
//! | [`TwistOrder`]: twist and offset | twist the offset solid | `twist-first` (offset the twisted surface: uniform wall) |
//!
//! Text form (problem files, `--variant`): `"spec"`, or the alternatives joined by `+`, e.g.
//! `"tips-on-r+outward+twist-first"`. The end-tangent angle of the lateral profile is a continuous
//! design parameter (`end_tangent_deg`), not part of the variant.

use std::fmt;

/// How the arc radius r maps onto the one-parameter (up to scale) family of equal-radius,
/// 3-fold, mirror-symmetric six-arc G1 rings.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum SectionReading {
    /// Spec (GEOMETRY.md §2): lobe chords on the sides of the equilateral triangle inscribed in
    /// the circle R.
    #[default]
    Triangle,
    /// GEOMETRY.md §8 (A): lobe tips on the circle R in the construction frame (d = R − r), so
    /// r is the true arc radius of the end sections.
    TipsOnR,
    /// Lobe centres on the edge midpoints of the inscribed triangle (d = R/2): the arcs of a
    /// triangular horseshoe lattice centred on its edges. Coincides with the spec at r = 5√3.
    MidpointCentres,
}

/// Which side of the designed (lofted) surface the wall of thickness t is laid.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum OffsetSide {
    /// Spec: offset inward, the designed surface is the outer surface (max radius R).
    #[default]
    Inward,
    /// Offset outward, the designed surface is the cavity (max outer radius R + t).
    Outward,
}

/// Order of the twist and the offset.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum TwistOrder {
    /// Spec (the letter's order): offset the untwisted loft, then twist the solid.
    #[default]
    AfterOffset,
    /// Twist the designed surface, then offset it along its own normal: a uniform wall of normal
    /// thickness t, trimmed by the end planes.
    BeforeOffset,
}

/// One reading of the geometry. `GeometryVariant::default()` is the spec.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct GeometryVariant {
    pub section: SectionReading,
    pub offset: OffsetSide,
    pub twist: TwistOrder,
}

/// The tokens of the text form: (token, what it sets).
const TOKENS: &[(&str, &str)] = &[
    ("spec", "the spec (GEOMETRY.md) for every choice not given"),
    ("tips-on-r", "section: lobe tips on R (d = R − r), GEOMETRY.md §8 (A)"),
    ("midpoint-centres", "section: lobe centres on the inscribed triangle's edge midpoints (d = R/2)"),
    ("outward", "wall: offset outward (the designed surface is the cavity)"),
    ("twist-first", "wall: twist the designed surface, then offset it (uniform wall)"),
];

/// The valid variant names, for messages.
pub fn variant_names() -> Vec<&'static str> {
    TOKENS.iter().map(|t| t.0).collect()
}

/// A one-line list of the valid names with what they mean.
pub fn variant_help() -> String {
    TOKENS.iter().map(|(t, what)| format!("{t} ({what})")).collect::<Vec<_>>().join(", ")
}

impl GeometryVariant {
    /// The spec (the default).
    pub fn spec() -> Self {
        GeometryVariant::default()
    }

    pub fn is_spec(&self) -> bool {
        *self == GeometryVariant::default()
    }

    /// Parse the text form: `spec`, or tokens joined by `+` (order free, each choice at most once).
    pub fn parse(text: &str) -> Result<Self, String> {
        let t = text.trim();
        let valid = || format!("valid values: {} (combine with '+', e.g. \"tips-on-r+outward+twist-first\")", variant_names().iter().map(|n| format!("\"{n}\"")).collect::<Vec<_>>().join(", "));
        if t.is_empty() {
            return Err(format!("empty geometry variant; {}", valid()));
        }
        let mut v = GeometryVariant::default();
        let (mut sec, mut off, mut tw) = (None::<&str>, None::<&str>, None::<&str>);
        for tok in t.split('+').map(str::trim) {
            let set = |slot: &mut Option<&str>, name: &'static str, what: &str| -> Result<(), String> {
                if let Some(prev) = slot {
                    return Err(format!("geometry variant '{t}': '{prev}' and '{name}' both set the {what}"));
                }
                *slot = Some(name);
                Ok(())
            };
            match tok.to_ascii_lowercase().as_str() {
                "spec" => {}
                "tips-on-r" => {
                    set(&mut sec, "tips-on-r", "section reading")?;
                    v.section = SectionReading::TipsOnR;
                }
                "midpoint-centres" => {
                    set(&mut sec, "midpoint-centres", "section reading")?;
                    v.section = SectionReading::MidpointCentres;
                }
                "outward" => {
                    set(&mut off, "outward", "offset side")?;
                    v.offset = OffsetSide::Outward;
                }
                "twist-first" => {
                    set(&mut tw, "twist-first", "twist order")?;
                    v.twist = TwistOrder::BeforeOffset;
                }
                other => return Err(format!("unknown geometry variant '{other}'; {}", valid())),
            }
        }
        Ok(v)
    }

    /// Canonical text form (`spec`, or the alternatives in the order section+offset+twist).
    pub fn name(&self) -> String {
        let mut parts = Vec::new();
        match self.section {
            SectionReading::Triangle => {}
            SectionReading::TipsOnR => parts.push("tips-on-r"),
            SectionReading::MidpointCentres => parts.push("midpoint-centres"),
        }
        if self.offset == OffsetSide::Outward {
            parts.push("outward");
        }
        if self.twist == TwistOrder::BeforeOffset {
            parts.push("twist-first");
        }
        if parts.is_empty() {
            "spec".into()
        } else {
            parts.join("+")
        }
    }

    /// Every combination of the three choices (12 variants, the spec first).
    pub fn all() -> Vec<GeometryVariant> {
        let mut out = Vec::new();
        for section in [SectionReading::Triangle, SectionReading::TipsOnR, SectionReading::MidpointCentres] {
            for offset in [OffsetSide::Inward, OffsetSide::Outward] {
                for twist in [TwistOrder::AfterOffset, TwistOrder::BeforeOffset] {
                    out.push(GeometryVariant { section, offset, twist });
                }
            }
        }
        out
    }
}

impl fmt::Display for GeometryVariant {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.name())
    }
}

impl std::str::FromStr for GeometryVariant {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        GeometryVariant::parse(s)
    }
}

impl TryFrom<String> for GeometryVariant {
    type Error = String;
    fn try_from(s: String) -> Result<Self, String> {
        GeometryVariant::parse(&s)
    }
}

impl From<GeometryVariant> for String {
    fn from(v: GeometryVariant) -> String {
        v.name()
    }
}

impl serde::Serialize for GeometryVariant {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(&self.name())
    }
}

impl<'de> serde::Deserialize<'de> for GeometryVariant {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let s = String::deserialize(d)?;
        GeometryVariant::parse(&s).map_err(serde::de::Error::custom)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parse_names_round_trip_and_errors() {
        assert!(GeometryVariant::parse("spec").unwrap().is_spec());
        assert_eq!(GeometryVariant::spec().name(), "spec");
        for v in GeometryVariant::all() {
            assert_eq!(GeometryVariant::parse(&v.name()).unwrap(), v, "{v}");
        }
        assert_eq!(GeometryVariant::all().len(), 12);
        let v = GeometryVariant::parse(" twist-first + Tips-on-R +spec").unwrap();
        assert_eq!(v.section, SectionReading::TipsOnR);
        assert_eq!(v.twist, TwistOrder::BeforeOffset);
        assert_eq!(v.offset, OffsetSide::Inward);
        assert_eq!(v.name(), "tips-on-r+twist-first");
        let e = GeometryVariant::parse("inward-ish").unwrap_err();
        assert!(e.contains("inward-ish") && e.contains("\"tips-on-r\"") && e.contains("\"spec\""), "{e}");
        let e = GeometryVariant::parse("tips-on-r+midpoint-centres").unwrap_err();
        assert!(e.contains("section reading"), "{e}");
        assert!(GeometryVariant::parse("").is_err());
        let json = serde_json::to_string(&GeometryVariant::parse("outward").unwrap()).unwrap();
        assert_eq!(json, "\"outward\"");
        let back: GeometryVariant = serde_json::from_str(&json).unwrap();
        assert_eq!(back.offset, OffsetSide::Outward);
    }
}

//! `nudge settings`: the reference of every planner and closed-loop setting (unit, default,
//! valid values, meaning), as the Markdown page `docs/reference/settings.md` or as JSON, both
//! from `nudge_sim::describe`.

use clap::{Args, ValueEnum};

/// Output format of `nudge settings`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum Format {
    /// The reference page (`docs/reference/settings.md`).
    Markdown,
    /// `{"PlannerSettings": [...], "SimConfig": [...]}`, one object per field (`field`,
    /// `unit`, `default`, `range`, `doc`).
    Json,
}

/// Arguments of `nudge settings`.
#[derive(Debug, Args)]
pub struct SettingsArgs {
    /// What to print.
    #[arg(long, value_enum, default_value_t = Format::Markdown)]
    pub format: Format,
}

/// The text `nudge settings` prints.
#[must_use]
pub fn render(args: &SettingsArgs) -> String {
    use nudge_sim::describe::{settings_json, settings_markdown};
    match args.format {
        Format::Markdown => settings_markdown(),
        Format::Json => serde_json::to_string_pretty(&settings_json()).unwrap_or_default() + "\n",
    }
}

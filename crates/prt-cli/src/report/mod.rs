//! What `prt bake` writes besides the container: `report.md` and `report.json` (markdown),
//! the slice images (images), the rendered views (renders) and the plots (plots).

mod images;
mod markdown;
mod plots;
mod renders;

pub use images::{save_png, write_images};
pub use markdown::{Report, table_markdown, write_report};
pub use plots::register_font;
pub use renders::{RenderSummary, rank_by_flip, write_renders};

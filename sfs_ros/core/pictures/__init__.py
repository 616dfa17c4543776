"""Pictures of a result for people: a PNG preview, a self-contained HTML viewer and a
contact sheet of the views."""

from .contact_sheet import contact_sheet, write_contact_sheet
from .html_viewer import html_viewer, write_html_viewer
from .preview import preview_image, write_png

__all__ = ["contact_sheet", "html_viewer", "preview_image", "write_contact_sheet",
           "write_html_viewer", "write_png"]

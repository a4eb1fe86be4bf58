"""Help menu dialogs: About (component versions) and the user guide (the documentation's tutorial and
how-to pages rendered in the app)."""

from __future__ import annotations

from PySide6.QtCore import QEvent, Qt
from PySide6.QtGui import QGuiApplication, QTextOption
from PySide6.QtWidgets import (QDialog, QDialogButtonBox, QHBoxLayout, QLabel, QPushButton, QTableWidget,
                               QTableWidgetItem, QTextBrowser, QVBoxLayout, QWidget, QHeaderView,
                               QAbstractItemView)

from lfstudio import __version__
from lfstudio.gui.bridge import run_off_gui
from lfstudio.gui.icons import app_icon
from lfstudio.gui.widgets import screen_fitted


class AboutDialog(QDialog):
    """lfstudio's version and every component's, gathered off the GUI thread (imports take a moment)."""

    def __init__(self, parent: QWidget | None = None):
        super().__init__(parent)
        self.setObjectName("aboutDialog")
        self.setWindowTitle("About lfstudio")
        self.setAttribute(Qt.WidgetAttribute.WA_DeleteOnClose)
        icon = QLabel()
        icon.setPixmap(app_icon().pixmap(96, 96))
        title = QLabel(f"<h2>lfstudio {__version__}</h2><p>Dense light-field acquisition with a two-axis "
                       "camera gantry: plan, capture, self-calibrate, process and export.</p>")
        title.setWordWrap(True)
        head = QHBoxLayout()
        head.addWidget(icon, 0, Qt.AlignmentFlag.AlignTop)
        head.addWidget(title, 1)

        self.table = QTableWidget(0, 2)
        self.table.setObjectName("versionsTable")
        self.table.setHorizontalHeaderLabels(["Component", "Version"])
        self.table.verticalHeader().setVisible(False)
        self.table.horizontalHeader().setSectionResizeMode(0, QHeaderView.ResizeMode.ResizeToContents)
        self.table.horizontalHeader().setStretchLastSection(True)
        self.table.setEditTriggers(QAbstractItemView.EditTrigger.NoEditTriggers)
        self.table.setToolTip("The versions of lfstudio and the libraries it uses (include them in bug reports)")
        self.status = QLabel("Reading component versions…")

        buttons = QDialogButtonBox(QDialogButtonBox.StandardButton.Close)
        self.copy_button = QPushButton("&Copy versions")
        self.copy_button.setToolTip("Copy this list to the clipboard (for a bug report)")
        self.copy_button.clicked.connect(self.copy_versions)
        buttons.addButton(self.copy_button, QDialogButtonBox.ButtonRole.ActionRole)
        buttons.rejected.connect(self.reject)

        lay = QVBoxLayout(self)
        lay.addLayout(head)
        lay.addWidget(self.table, 1)
        lay.addWidget(self.status)
        lay.addWidget(buttons)
        self.resize(screen_fitted(self, 640, 520))
        self.rows: list[tuple[str, str]] = []
        from lfstudio.support.versions import versions

        self._gathering = run_off_gui(self, versions, self._fill)     # imports take a moment

    def _fill(self, rows) -> None:
        self.rows = list(rows)
        self.table.setRowCount(len(self.rows))
        for i, (name, text) in enumerate(self.rows):
            self.table.setItem(i, 0, QTableWidgetItem(name))
            item = QTableWidgetItem(text)
            item.setToolTip(text)
            self.table.setItem(i, 1, item)
        self.status.setText(f"{len(self.rows)} entries")

    def text(self) -> str:
        return "\n".join(f"{name}: {text}" for name, text in self.rows)

    def copy_versions(self) -> None:
        QGuiApplication.clipboard().setText(self.text())
        self.copy_button.setText("Copied")


class UserGuideDialog(QDialog):
    """The user guide (:func:`lfstudio.support.userguide.user_guide_markdown`), rendered from Markdown (also in
    a bundle or an installed copy)."""

    def __init__(self, parent: QWidget | None = None):
        super().__init__(parent)
        from lfstudio.support.userguide import NO_SITE_NOTE, docs_dir, readme_path, site_dir, user_guide_markdown

        self.setObjectName("userGuideDialog")
        self.setWindowTitle("lfstudio user guide")
        self.setAttribute(Qt.WidgetAttribute.WA_DeleteOnClose)
        self.browser = QTextBrowser()
        self.browser.setObjectName("userGuideBrowser")
        self.browser.setOpenExternalLinks(True)
        self.browser.setWordWrapMode(QTextOption.WrapMode.WrapAtWordBoundaryOrAnywhere)   # a long path breaks too
        self._image_sizes: dict[str, tuple[int, int]] = {}     # a picture's (width, height) by name
        self.browser.viewport().installEventFilter(self)
        docs, readme = docs_dir(), readme_path()
        base = docs.parent if docs is not None else readme.parent if readme is not None else None
        if base is not None:            # the guide's pictures (docs/*.png) and README.md sit there
            self.browser.setSearchPaths([str(base)])
        note = NO_SITE_NOTE + "\n\n" if site_dir() is None else ""     # how to get search and contents
        self.browser.setMarkdown(note + user_guide_markdown())
        self._wrap_code_blocks()
        self.fit_images(760)
        buttons = QDialogButtonBox(QDialogButtonBox.StandardButton.Close)
        buttons.rejected.connect(self.reject)
        lay = QVBoxLayout(self)
        lay.addWidget(self.browser, 1)
        lay.addWidget(buttons)
        self.resize(screen_fitted(self, 860, 760))

    def _wrap_code_blocks(self) -> None:
        """Command lines wrap at the page's edge like the prose (a code block is a non-breaking block
        in Qt's Markdown), so the guide never scrolls sideways on a small screen."""
        from PySide6.QtGui import QTextCursor

        doc = self.browser.document()
        block = doc.begin()
        while block.isValid():
            fmt = block.blockFormat()
            if fmt.nonBreakableLines():
                fmt.setNonBreakableLines(False)
                QTextCursor(block).setBlockFormat(fmt)
            block = block.next()

    def eventFilter(self, watched, event) -> bool:
        if watched is self.browser.viewport() and event.type() == QEvent.Type.Resize:
            margin = int(self.browser.document().documentMargin())
            self.fit_images(min(760, max(120, event.size().width() - 2 * margin - 8)))   # pictures fit the page
        return super().eventFilter(watched, event)

    def fit_images(self, max_width_px: int) -> int:
        """Show the guide's pictures (full-window screenshots) at most ``max_width_px`` wide, never
        wider than they are; returns how many changed."""
        from PySide6.QtCore import QUrl
        from PySide6.QtGui import QImage, QTextCursor, QTextDocument

        doc = self.browser.document()
        scaled = 0
        block = doc.begin()
        while block.isValid():
            it = block.begin()
            while not it.atEnd():
                frag = it.fragment()
                fmt = frag.charFormat()
                if fmt.isImageFormat():
                    img = fmt.toImageFormat()
                    size = self._image_sizes.get(img.name())
                    if size is None:            # read and decoded once, not at every resize
                        data = self.browser.loadResource(QTextDocument.ResourceType.ImageResource, QUrl(img.name()))
                        image = QImage.fromData(data) if data is not None else QImage()
                        size = self._image_sizes[img.name()] = (image.width(), image.height())
                    width, height = size
                    shown_px = img.width() if img.width() > 0 else width
                    wanted = min(max_width_px, width)
                    if width > 0 and abs(shown_px - wanted) >= 1:
                        img.setWidth(wanted)
                        img.setHeight(height * wanted / width)
                        cursor = QTextCursor(doc)
                        cursor.setPosition(frag.position())
                        cursor.setPosition(frag.position() + frag.length(), QTextCursor.MoveMode.KeepAnchor)
                        cursor.setCharFormat(img)
                        scaled += 1
                it += 1
            block = block.next()
        return scaled
